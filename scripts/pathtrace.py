#!/usr/bin/env python3
"""Path-traced per-node radiosity with Mitsuba 3, for `radiosity-lab accuracy`.

Reads the scene that `radiosity-lab accuracy` exports (JSON: per glTF node its
world-space triangles, reflectance and emitted radiance), builds a Mitsuba
scene with one-sided diffuse surfaces and area emitters (the renderer's
conventions, DESIGN.md section 6), and estimates every node's irradiance with
an `irradiancemeter` sensor attached to it (uniform over its area, cosine-
weighted directions). Radiosity B = rho * E + pi * L_e per channel.

It renders at sample counts that double from --min-spp to --max-spp and prints
one JSON line per level: {"spp", "seconds", "surfaces": [{"node", "area",
"radiosity"}]}, where seconds is the total render time over all nodes at that
level (scene loading excluded, as device set-up is excluded on our side).

The first line printed is {"variant": NAME}.

Usage: pathtrace.py SCENE.json [--variant auto] [--min-spp 4] [--max-spp 4096]
Install: pip install mitsuba (llvm_ad_rgb needs Debian's libllvm19; scalar_rgb runs anywhere).
"""

import argparse
import json
import os
import sys
import tempfile
import time


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("scene")
    ap.add_argument("--variant", default="auto",
                    help="a Mitsuba variant; auto: llvm_ad_rgb when it loads, else scalar_rgb")
    ap.add_argument("--min-spp", type=int, default=4)
    ap.add_argument("--max-spp", type=int, default=4096)
    ap.add_argument("--max-seconds", type=float, default=120.0,
                    help="stop doubling once a level took longer than this")
    args = ap.parse_args()

    try:
        import drjit as dr
        import mitsuba as mi
    except ImportError:
        sys.exit("pathtrace.py: Mitsuba 3 is not installed: pip install mitsuba")
    if args.variant == "auto":
        try:
            mi.set_variant("llvm_ad_rgb")
        except Exception:  # no usable LLVM (Debian 12: apt-get install libllvm19)
            mi.set_variant("scalar_rgb")
    else:
        mi.set_variant(args.variant)
    print(json.dumps({"variant": mi.variant()}), flush=True)

    with open(args.scene) as f:
        scene = json.load(f)

    tmp = tempfile.mkdtemp(prefix="pathtrace-")
    shapes = {}
    for i, node in enumerate(scene["nodes"]):
        tris = node["triangles"]
        if not tris:
            continue
        path = os.path.join(tmp, f"n{i}.obj")
        with open(path, "w") as obj:
            for t in tris:
                for v in t:
                    obj.write(f"v {v[0]!r} {v[1]!r} {v[2]!r}\n")
            for k in range(len(tris)):
                obj.write(f"f {3 * k + 1} {3 * k + 2} {3 * k + 3}\n")
        shape = {
            "type": "obj",
            "filename": path,
            "face_normals": True,
            "bsdf": {"type": "diffuse",
                     "reflectance": {"type": "rgb", "value": node["reflectance"]}},
        }
        if any(e > 0 for e in node["emission"]):
            shape["emitter"] = {"type": "area",
                                "radiance": {"type": "rgb", "value": node["emission"]}}
        shapes[i] = shape

    def build(spp):
        d = {"type": "scene", "integrator": {"type": "path", "max_depth": -1}}
        for i, shape in shapes.items():
            s = dict(shape)
            s["sensor"] = {
                "type": "irradiancemeter",
                "film": {"type": "hdrfilm", "width": 1, "height": 1,
                         "rfilter": {"type": "box"}, "pixel_format": "rgb"},
                "sampler": {"type": "independent", "sample_count": spp},
            }
            d[f"n{i}"] = s
        # optimize=False: the parser would otherwise merge the identical
        # sensor dictionaries into one sensor shared by every shape.
        return mi.load_dict(d, optimize=False)

    # Warm up: the LLVM variant compiles its kernels on the first renders;
    # that one-off cost is left out as our device set-up is.
    for k in range(3):
        warm = build(args.min_spp << k)
        for sh in warm.shapes():
            if sh.sensor() is not None:
                img = mi.render(warm, sensor=sh.sensor(), spp=args.min_spp << k, seed=0)
                dr.eval(img)
                dr.sync_thread()
                break

    spp = args.min_spp
    seed = 1
    while spp <= args.max_spp:
        sc = build(spp)
        # Each sensor belongs to the shape it is nested in; shape ids are the dict keys.
        by_id = {sh.id(): sh.sensor() for sh in sc.shapes() if sh.sensor() is not None}
        surfaces = []
        seconds = 0.0
        for i in shapes:
            node = scene["nodes"][i]
            t = time.perf_counter()
            img = mi.render(sc, sensor=by_id[f"n{i}"], spp=spp, seed=seed)
            # Dr.Jit evaluates lazily: finish the work inside the timed region.
            dr.eval(img)
            dr.sync_thread()
            seconds += time.perf_counter() - t
            # A 1 x 1 RGB film: the tensor's first three values.
            flat = mi.TensorXf(img).array
            e = [float(flat[c]) for c in range(3)]
            rho, le = node["reflectance"], node["emission"]
            b = [rho[c] * e[c] + 3.141592653589793 * le[c] for c in range(3)]
            surfaces.append({"node": node["name"], "area": node["area"], "radiosity": b})
        print(json.dumps({"spp": spp, "seconds": seconds, "surfaces": surfaces}), flush=True)
        seed += 1
        if seconds > args.max_seconds:
            break
        spp *= 2


if __name__ == "__main__":
    main()
