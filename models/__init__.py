"""Symbolic models of the dynamic visual feedback system (CasADi): the single source
of truth for the simulator, the verifier and the certifier."""
