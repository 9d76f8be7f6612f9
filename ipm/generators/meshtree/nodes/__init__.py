"""Mesh node types, one topic per module (primitives; transforms and merge). Every module here is
imported by the registry :data:`ipm.generators.meshtree.node.MESH_NODES` on first use."""
