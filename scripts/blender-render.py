"""Renders a baked glTF (radiosity render --bake) in Blender, as the README's
picture was made: imports it with Blender's own glTF importer, uses the
file's camera, Cycles on the CPU (the unlit materials show the vertex
colours as they are), standard view transform.

    pip install bpy        # Blender as a Python module (large)
    python3 scripts/blender-render.py out/cornell.glb docs/bake-blender.png
"""
import sys

import bpy

src, dst = sys.argv[1], sys.argv[2]
bpy.ops.wm.read_factory_settings(use_empty=True)
bpy.ops.import_scene.gltf(filepath=src)
scene = bpy.context.scene
cameras = [o for o in scene.objects if o.type == "CAMERA"]
if not cameras:
    sys.exit(f"{src}: no camera in the file")
scene.camera = cameras[0]
scene.render.engine = "CYCLES"
scene.cycles.device = "CPU"
scene.cycles.samples = 8
scene.render.resolution_x = 480
scene.render.resolution_y = 480
scene.view_settings.view_transform = "Standard"
scene.render.filepath = dst
bpy.ops.render.render(write_still=True)
print("rendered", dst)
