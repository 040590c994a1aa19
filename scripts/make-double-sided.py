#!/usr/bin/env python3
"""Writes a copy of a glTF scene with every material double-sided, for the
memory benchmark (issue 64 item 6: a scene whose every material is
double-sided doubles its polygons). The copy goes in DST_DIR beside links to
the source's buffers and images, so relative URIs still resolve.

    python3 scripts/make-double-sided.py ../shared/scenes/sponza/Sponza.gltf /tmp/ds
    python3 scripts/make-double-sided.py --architecture ... # Sponza without its
        # plants, fabrics and vases, and the plants' masks off (169 326 polygons)
"""
import argparse
import json
import os


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("src")
    ap.add_argument("dst_dir")
    ap.add_argument("--architecture", action="store_true",
                    help="drop the nodes of meshes with Sponza's plant, fabric and vase materials")
    args = ap.parse_args()
    doc = json.load(open(args.src))
    for m in doc.get("materials", []):
        m["doubleSided"] = True
    if args.architecture:
        drop = set()
        for i, mesh in enumerate(doc["meshes"]):
            names = {doc["materials"][p.get("material", 0)].get("name", "")
                     for p in mesh["primitives"]}
            if any(n.startswith(("Plants", "PotPlant", "Fabric", "Vase")) for n in names):
                drop.add(i)
        for m in doc["materials"]:
            m.pop("alphaMode", None)
            m.pop("alphaCutoff", None)
        for s in doc["scenes"]:
            s["nodes"] = [n for n in s["nodes"] if doc["nodes"][n].get("mesh") not in drop]
    os.makedirs(args.dst_dir, exist_ok=True)
    src_dir = os.path.dirname(os.path.abspath(args.src))
    for name in os.listdir(src_dir):
        link = os.path.join(args.dst_dir, name)
        if name != os.path.basename(args.src) and not os.path.lexists(link):
            os.symlink(os.path.join(src_dir, name), link)
    out = os.path.join(args.dst_dir, os.path.basename(args.src))
    with open(out + ".tmp", "w") as f:
        json.dump(doc, f)
    os.replace(out + ".tmp", out)
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
