"""The hand-written C sources of an exported controller (templates filled by :mod:`dvfc.analysis.export`)."""
