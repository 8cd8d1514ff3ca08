"""Render a geovox .vdb in Blender, headless: the picture in the README.

    blender -b -P docs/render_vdb_blender.py -- spot.vdb docs/spot_vdb_blender.png

Imports the file as a volume object (Blender reads the grids `density` and
`color` by name), shades it with a Principled Volume whose colour comes from
the `color` grid, and renders one frame with Cycles on the CPU.
"""

import math
import sys

import bpy
from mathutils import Vector

vdb_path, png_path = sys.argv[sys.argv.index("--") + 1:][:2]

bpy.ops.wm.read_factory_settings(use_empty=True)
scene = bpy.context.scene

bpy.ops.object.volume_import(filepath=vdb_path)
vol = bpy.context.active_object
# OBJ models (spot among them) are y-up; Blender is z-up.
vol.rotation_euler = (math.pi / 2, 0.0, 0.0)
bpy.context.view_layer.update()

# Principled Volume: density from the `density` grid, colour from `color`.
mat = bpy.data.materials.new("geovox")
mat.use_nodes = True
nodes, links = mat.node_tree.nodes, mat.node_tree.links
nodes.clear()
out = nodes.new("ShaderNodeOutputMaterial")
shader = nodes.new("ShaderNodeVolumePrincipled")
shader.inputs["Density"].default_value = 40.0
shader.inputs["Density Attribute"].default_value = "density"
shader.inputs["Color"].default_value = (1.0, 1.0, 1.0, 1.0)
shader.inputs["Color Attribute"].default_value = "color"  # multiplies Color
links.new(shader.outputs["Volume"], out.inputs["Volume"])
vol.data.materials.append(mat)

# Frame the volume: its bounding box in world space.
corners = [vol.matrix_world @ Vector(c) for c in vol.bound_box]
centre = sum(corners, Vector()) / 8
radius = max((c - centre).length for c in corners)

cam_data = bpy.data.cameras.new("camera")
cam = bpy.data.objects.new("camera", cam_data)
scene.collection.objects.link(cam)
direction = Vector((1.3, -1.6, 0.7)).normalized()
cam.location = centre + direction * radius * 2.8
cam.rotation_euler = (centre - cam.location).to_track_quat("-Z", "Y").to_euler()
scene.camera = cam

for energy, offset in ((1500.0, (2, -2, 3)), (600.0, (-3, 1, 2))):
    light = bpy.data.objects.new("light", bpy.data.lights.new("light", "POINT"))
    light.data.energy = energy * radius ** 2
    light.location = centre + Vector(offset) * radius
    scene.collection.objects.link(light)

world = bpy.data.worlds.new("world")
world.color = (0.05, 0.05, 0.06)
scene.world = world

scene.render.engine = "CYCLES"
scene.cycles.device = "CPU"
scene.cycles.samples = 32
scene.cycles.use_denoising = False  # Debian's build has no OpenImageDenoise
scene.cycles.volume_step_rate = 1.0
scene.render.resolution_x, scene.render.resolution_y = 640, 480
scene.render.image_settings.file_format = "PNG"
scene.render.filepath = png_path
bpy.ops.render.render(write_still=True)
