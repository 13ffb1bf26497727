"""Scene files (TOML) and running them: the schema, the physics of a scene on any backend, obstacles
and the pipeline from scene file to PNG.
"""
