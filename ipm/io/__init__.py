"""Files: atomic writes, mesh export, masks and run folders."""
