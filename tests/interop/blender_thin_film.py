#!/usr/bin/env python3
"""Load a filmscope GLB in Blender and give its Principled BSDF the film: a manual check of
`export-gltf` in Blender (not run by CI; it needs the `bpy` wheel, about 1 GB installed).

    python3 -m venv DIR && DIR/bin/pip install bpy
    DIR/bin/python tests/interop/blender_thin_film.py sample.glb [render.png]

Blender's glTF importer reads `KHR_materials_ior` into the Principled BSDF's IOR. Importers
without `KHR_materials_iridescence` (Blender 5.0.1, the latest bpy wheel when this was
written) leave `Thin Film Thickness` at 0, so this script wires it from the file itself,
as one would by hand:

    Image Texture (the GLB's thickness PNG, Non-Color)
      -> Separate Color (RGB), Green
      -> Map Range (0..1 -> iridescenceThicknessMinimum..Maximum, nm)
      -> Principled BSDF: Thin Film Thickness
    Principled BSDF: Thin Film IOR = iridescenceIor

It prints what the importer set and what was wired, and with a second argument renders the
quad with Cycles (CPU, uniform white world, camera about 49 degrees from the normal).
"""
import json
import pathlib
import struct
import sys
import tempfile

import bpy


def read_glb(path):
    data = pathlib.Path(path).read_bytes()
    magic, version, _ = struct.unpack_from("<4sII", data, 0)
    assert magic == b"glTF" and version == 2
    json_len, _ = struct.unpack_from("<II", data, 12)
    doc = json.loads(data[20 : 20 + json_len])
    at = 20 + json_len
    bin_len, _ = struct.unpack_from("<II", data, at)
    return doc, data[at + 8 : at + 8 + bin_len]


def main():
    glb = sys.argv[1]
    doc, binary = read_glb(glb)
    ext = doc["materials"][0]["extensions"]
    iri = ext["KHR_materials_iridescence"]
    image = doc["images"][doc["textures"][iri["iridescenceThicknessTexture"]["index"]]["source"]]
    view = doc["bufferViews"][image["bufferView"]]
    png = binary[view.get("byteOffset", 0) : view.get("byteOffset", 0) + view["byteLength"]]

    bpy.ops.wm.read_factory_settings(use_empty=True)
    bpy.ops.import_scene.gltf(filepath=glb)
    print("blender", bpy.app.version_string)
    mat = bpy.data.materials[doc["materials"][0]["name"]]
    nodes, links = mat.node_tree.nodes, mat.node_tree.links
    bsdf = next(n for n in nodes if n.type == "BSDF_PRINCIPLED")
    print("imported: IOR %.4f, Thin Film Thickness %.1f, Thin Film IOR %.4f" % (
        bsdf.inputs["IOR"].default_value,
        bsdf.inputs["Thin Film Thickness"].default_value,
        bsdf.inputs["Thin Film IOR"].default_value,
    ))
    if not bsdf.inputs["Thin Film Thickness"].links:
        tmp = pathlib.Path(tempfile.mkdtemp()) / "thickness.png"
        tmp.write_bytes(png)
        tex = nodes.new("ShaderNodeTexImage")
        tex.image = bpy.data.images.load(str(tmp))
        tex.image.colorspace_settings.name = "Non-Color"
        sep = nodes.new("ShaderNodeSeparateColor")
        rng = nodes.new("ShaderNodeMapRange")
        rng.inputs["From Min"].default_value = 0.0
        rng.inputs["From Max"].default_value = 1.0
        rng.inputs["To Min"].default_value = iri["iridescenceThicknessMinimum"]
        rng.inputs["To Max"].default_value = iri["iridescenceThicknessMaximum"]
        links.new(tex.outputs["Color"], sep.inputs["Color"])
        links.new(sep.outputs["Green"], rng.inputs["Value"])
        links.new(rng.outputs["Result"], bsdf.inputs["Thin Film Thickness"])
        bsdf.inputs["Thin Film IOR"].default_value = iri["iridescenceIor"]
        print("wired: Thin Film Thickness <- G of the thickness texture mapped to %.1f..%.1f nm, "
              "Thin Film IOR %.4f" % (iri["iridescenceThicknessMinimum"],
                                      iri["iridescenceThicknessMaximum"], iri["iridescenceIor"]))
    if len(sys.argv) > 2:
        scene = bpy.context.scene
        scene.render.engine = "CYCLES"
        scene.cycles.device = "CPU"
        scene.cycles.samples = 32
        scene.render.resolution_x, scene.render.resolution_y = 600, 400
        scene.view_settings.view_transform = "Standard"
        scene.view_settings.exposure = 3.0
        world = bpy.data.worlds.new("white")
        world.use_nodes = True
        world.node_tree.nodes["Background"].inputs["Color"].default_value = (1, 1, 1, 1)
        scene.world = world
        cam = bpy.data.objects.new("camera", bpy.data.cameras.new("camera"))
        cam.location = (0.0, -0.16, 0.14)
        cam.data.lens = 50
        scene.collection.objects.link(cam)
        target = bpy.data.objects.new("target", None)
        scene.collection.objects.link(target)
        track = cam.constraints.new("TRACK_TO")
        track.target = target
        scene.camera = cam
        scene.render.filepath = sys.argv[2]
        bpy.ops.render.render(write_still=True)
        print("rendered", sys.argv[2])


if __name__ == "__main__":
    main()
