#!/usr/bin/env python3
"""Writes tests/fixtures/emissive/panel-room.gltf: a closed 2 m room (grey
walls, reflectance 0.5) lit only by a 1 m ceiling panel whose emission is an
emissive texture, its -x half white and its +x half black (an 8 x 1 PNG,
sampler clamped), emissiveFactor 1 and KHR_materials_emissive_strength 10:
radiance 10 W sr^-1 m^-2 on the lit half, 0 on the other. The panel itself
reflects nothing; a camera on the floor looks up at it. Self-contained (buffers and image as data URIs).

    python3 scripts/make-emissive-scene.py
"""
import base64
import json
import os
import struct
import zlib


def png(texels):
    """An RGB PNG, len(texels) x 1, of grey levels."""
    raw = b"\x00" + bytes(v for g in texels for v in (g, g, g))
    def chunk(kind, data):
        c = struct.pack(">I", len(data)) + kind + data
        return c + struct.pack(">I", zlib.crc32(kind + data) & 0xFFFFFFFF)
    ihdr = struct.pack(">IIBBBBB", len(texels), 1, 8, 2, 0, 0, 0)
    return (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr)
            + chunk(b"IDAT", zlib.compress(raw)) + chunk(b"IEND", b""))


def rect(axis, at, lo, hi, positive):
    """As src/scene/gltf_write.rs's axis_rect."""
    a, b = (axis + 1) % 3, (axis + 2) % 3
    def p(u, v):
        c = [0.0, 0.0, 0.0]
        c[axis], c[a], c[b] = at, u, v
        return c
    q = [p(lo[0], lo[1]), p(hi[0], lo[1]), p(hi[0], hi[1]), p(lo[0], hi[1])]
    return q if positive else q[::-1]


def main():
    surfaces = [
        ("floor", rect(1, 0.0, (-1, -1), (1, 1), True)),
        ("ceiling", rect(1, 2.0, (-1, -1), (1, 1), False)),
        ("wall_left", rect(0, -1.0, (0, -1), (2, 1), True)),
        ("wall_right", rect(0, 1.0, (0, -1), (2, 1), False)),
        ("wall_back", rect(2, -1.0, (-1, 0), (1, 2), True)),
        ("wall_front", rect(2, 1.0, (-1, 0), (1, 2), False)),
        ("panel", rect(1, 1.99, (-0.5, -0.5), (0.5, 0.5), False)),
    ]
    buf = b""
    views, accessors, meshes, nodes, materials = [], [], [], [], []
    for i, (name, quad) in enumerate(surfaces):
        attributes = {}
        pos = b"".join(struct.pack("<3f", *v) for v in quad)
        views.append({"buffer": 0, "byteOffset": len(buf), "byteLength": len(pos)})
        lo = [min(v[k] for v in quad) for k in range(3)]
        hi = [max(v[k] for v in quad) for k in range(3)]
        accessors.append({"bufferView": len(views) - 1, "componentType": 5126,
                          "count": 4, "type": "VEC3", "min": lo, "max": hi})
        attributes["POSITION"] = len(accessors) - 1
        buf += pos
        if name == "panel":
            # u runs with x over the panel, v the texture's one row.
            uv = b"".join(struct.pack("<2f", v[0] + 0.5, 0.5) for v in quad)
            views.append({"buffer": 0, "byteOffset": len(buf), "byteLength": len(uv)})
            accessors.append({"bufferView": len(views) - 1, "componentType": 5126,
                              "count": 4, "type": "VEC2"})
            attributes["TEXCOORD_0"] = len(accessors) - 1
            buf += uv
        idx = struct.pack("<6H", 0, 1, 2, 0, 2, 3) + b"\x00\x00"
        views.append({"buffer": 0, "byteOffset": len(buf), "byteLength": 12})
        accessors.append({"bufferView": len(views) - 1, "componentType": 5123,
                          "count": 6, "type": "SCALAR"})
        buf += idx
        if name == "panel":
            materials.append({
                "name": "panel",
                "pbrMetallicRoughness": {"baseColorFactor": [0, 0, 0, 1], "metallicFactor": 0},
                "emissiveFactor": [1, 1, 1],
                "emissiveTexture": {"index": 0},
                "extensions": {"KHR_materials_emissive_strength": {"emissiveStrength": 10}},
            })
        else:
            materials.append({"name": "grey",
                              "pbrMetallicRoughness": {"baseColorFactor": [0.5, 0.5, 0.5, 1],
                                                       "metallicFactor": 0}})
        meshes.append({"name": name, "primitives": [
            {"attributes": attributes, "indices": len(accessors) - 1, "material": i}]})
        nodes.append({"name": name, "mesh": i, "extras": {"radiosity": {
            "patches": [4, 4] if name == "panel" else [2, 2], "elements": [2, 2]}}})
    # A camera on the floor looking up at the panel (its -x half on the
    # image's left).
    nodes.append({"name": "camera", "camera": 0, "translation": [0, 0.2, 0],
                  "rotation": [0.70710678, 0, 0, 0.70710678]})
    image = png([255] * 4 + [0] * 4)
    doc = {
        "asset": {"version": "2.0", "generator": "scripts/make-emissive-scene.py"},
        "extensionsUsed": ["KHR_materials_emissive_strength"],
        "scene": 0, "scenes": [{"nodes": list(range(len(nodes)))}],
        "nodes": nodes, "meshes": meshes,
        "cameras": [{"type": "perspective",
                     "perspective": {"yfov": 0.8, "aspectRatio": 1, "znear": 0.01}}], "materials": materials,
        "accessors": accessors, "bufferViews": views,
        "buffers": [{"byteLength": len(buf),
                     "uri": "data:application/octet-stream;base64," + base64.b64encode(buf).decode()}],
        "images": [{"uri": "data:image/png;base64," + base64.b64encode(image).decode()}],
        "samplers": [{"wrapS": 33071, "wrapT": 33071, "magFilter": 9729}],
        "textures": [{"source": 0, "sampler": 0}],
    }
    out = os.path.join(os.path.dirname(__file__), "..", "tests", "fixtures", "emissive", "panel-room.gltf")
    with open(out, "w") as f:
        json.dump(doc, f, indent=1)
        f.write("\n")
    print(out)


if __name__ == "__main__":
    main()
