"""The scene files (TOML) and meshes of deformgl, shipped inside the wheel; see deformgl.data."""
