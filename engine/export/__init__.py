"""A fitted run -> UV + alpha passes, atlas textures, edit layers and the manifest Blender reads."""
