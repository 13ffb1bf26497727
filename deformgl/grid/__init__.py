"""The node grid and the geometry it comes from: mesh loading, voxelization of a mesh into grid
nodes, the node grid and its texture layouts, the grid's surface. CPU only.
"""
