"""Subdivision schemes, one module each, registered in :data:`ipm.subdiv.SCHEMES`."""
