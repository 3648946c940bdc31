"""Reports of the analysis: figures and documents."""
