"""Analysis of the dynamic visual feedback system: simulation, verification, certification, CLI."""
