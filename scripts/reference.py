#!/usr/bin/env python3
"""Per-node reference radiosity by path tracing with next-event estimation
(Mitsuba 3), to a stated standard error: the independent yardstick.

Reads the node JSON that `radiosity scene NAME --nodes OUT.json` writes (per
glTF node its world-space triangles, reflectance, emitted radiance, area),
builds a Mitsuba scene of one-sided diffuse surfaces and area emitters (the
renderer's conventions), and estimates each node's mean irradiance E over
its area: at points sampled uniformly over the node, one emitter sample and
one cosine-weighted direction, combined by multiple importance sampling
(power heuristic); the cosine direction's radiance comes from Mitsuba's path
integrator (which samples the emitters at every later vertex too).
B = rho * E + pi * L_e per channel. Samples come in batches until every
node's relative standard error of B (sum over RGB) is at most --target, or
--max-seconds pass.

Prints one JSON document: {"how", "variant", "seconds", "surfaces": [{"node",
"area", "radiosity", "standard_error"}]}.

With --image OUT.exr it renders the camera image instead (the camera that
the node JSON carries, the renderer's own): Mitsuba's path integrator (next-
event estimation at every vertex, MIS), a box filter over each pixel like the
renderer's supersampling, in --passes independent passes whose spread gives
each 4x4 block's standard error; OUT.exr gets the mean, OUT.json (beside it)
the command, the passes and the block errors.

Usage: reference.py NODES.json [--target 1e-3] [--batch 65536] [--max-seconds 600] [--trace]
       reference.py NODES.json --image OUT.exr --width 128 --height 128 --spp 4096 [--passes 8]
Install: pip install mitsuba (and numpy for --image)
"""

import argparse
import json
import math
import os
import sys
import tempfile

# The highest reflectance a texel may give (src/scene/texture.rs).
MAX_REFLECTANCE = 0.95
import time


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("nodes")
    ap.add_argument("--variant", default="llvm_ad_rgb")
    ap.add_argument("--target", type=float, default=1e-3,
                    help="relative standard error of every node's radiosity")
    ap.add_argument("--batch", type=int, default=1 << 16, help="points per node per batch")
    ap.add_argument("--max-seconds", type=float, default=600.0)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--trace", action="store_true",
                    help="print one JSON line per round of batches (points per node, "
                         "seconds, surfaces) for error-against-time charts, kernels "
                         "compiled before the clock starts")
    ap.add_argument("--image", help="render the camera image to this EXR instead")
    ap.add_argument("--width", type=int, default=128)
    ap.add_argument("--height", type=int, help="default: width over the camera's aspect ratio, as the renderer")
    ap.add_argument("--spp", type=int, default=4096, help="samples per pixel, all passes together")
    ap.add_argument("--passes", type=int, default=8)
    args = ap.parse_args()
    try:
        import drjit as dr
        import mitsuba as mi
    except ImportError:
        sys.exit("reference.py: Mitsuba 3 is not installed: pip install mitsuba")
    mi.set_variant(args.variant)
    with open(args.nodes) as f:
        doc = json.load(f)
    nodes = [n for n in doc["nodes"] if n["triangles"]]

    # Faces that coincide back to back (a wall given as two one-sided faces,
    # as double-sided exports give them) would tie in a ray tracer, which then
    # hits either: half the rays would meet a black back face. Each face is
    # moved a hair (1e-5 of the scene's size) along its normal, so the face
    # that faces a ray is always the nearer one, as in the renderer (where a
    # back face sits a hair behind a coincident front face).
    lo = [min(v[k] for n in nodes for t in n["triangles"] for v in t) for k in range(3)]
    hi = [max(v[k] for n in nodes for t in n["triangles"] for v in t) for k in range(3)]
    eps = 1e-5 * math.sqrt(sum((hi[k] - lo[k]) ** 2 for k in range(3)))

    def lifted(t):
        a, b, c = t
        u = [b[k] - a[k] for k in range(3)]
        v = [c[k] - a[k] for k in range(3)]
        n = [u[1] * v[2] - u[2] * v[1], u[2] * v[0] - u[0] * v[2], u[0] * v[1] - u[1] * v[0]]
        ln = math.sqrt(sum(x * x for x in n)) or 1.0
        return [[p[k] + eps * n[k] / ln for k in range(3)] for p in t]

    for node in nodes:
        node["triangles"] = [lifted(t) for t in node["triangles"]]

    tmp = tempfile.mkdtemp(prefix="reference-")
    d = {"type": "scene"}
    textures = {}
    for i, node in enumerate(nodes):
        path = os.path.join(tmp, f"n{i}.obj")
        tex = node.get("texture")
        emissive = node.get("emissive_texture")
        # One set of coordinates a shape: a node's two textures must share it.
        uvs = node.get("uvs") if tex else node.get("emissive_uvs")
        if tex and emissive and node["emissive_uvs"] != node["uvs"]:
            sys.exit(f"reference.py: node {node['name']} maps its base colour and emissive textures differently")
        with open(path, "w") as obj:
            for t in node["triangles"]:
                for v in t:
                    obj.write(f"v {v[0]!r} {v[1]!r} {v[2]!r}\n")
            if uvs:
                # OBJ's v runs up, glTF's down: Mitsuba's loader flips it
                # back (flip_tex_coords), so shapes see glTF's v as
                # batch() does.
                for t in uvs:
                    for uv in t:
                        obj.write(f"vt {uv[0]!r} {1.0 - uv[1]!r}\n")
                for k in range(len(node["triangles"])):
                    a, b, c = 3 * k + 1, 3 * k + 2, 3 * k + 3
                    obj.write(f"f {a}/{a} {b}/{b} {c}/{c}\n")
            else:
                for k in range(len(node["triangles"])):
                    obj.write(f"f {3 * k + 1} {3 * k + 2} {3 * k + 3}\n")
        reflectance = {"type": "rgb", "value": node["reflectance"]}
        if tex:
            reflectance = bitmap(mi, tex, args, tmp, f"tex{i}", MAX_REFLECTANCE)
            textures[i] = mi.load_dict(reflectance)
        shape = {"type": "obj", "filename": path, "face_normals": True,
                 "bsdf": {"type": "diffuse", "reflectance": reflectance}}
        if emissive:
            shape["emitter"] = {"type": "area",
                                "radiance": bitmap(mi, emissive, args, tmp, f"emission{i}", None)}
        elif any(e > 0 for e in node["emission"]):
            shape["emitter"] = {"type": "area",
                                "radiance": {"type": "rgb", "value": node["emission"]}}
        d[f"n{i}"] = shape
    # Lights that are not surfaces (the renderer's KHR_lights_punctual,
    # --sun, --sky), in the same units.
    for k, light in enumerate(doc.get("lights", [])):
        rgb = {"type": "rgb", "value": light["intensity"]}
        if light["kind"] == "point":
            d[f"light{k}"] = {"type": "point", "position": light["position"], "intensity": rgb}
        elif light["kind"] == "directional":
            d[f"light{k}"] = {"type": "directional", "direction": light["direction"], "irradiance": rgb}
        else:
            # Mitsuba's spot falls off differently from glTF's.
            sys.exit(f"reference.py: a {light['kind']} light has no Mitsuba counterpart here")
    if doc.get("sky") and doc.get("sky_map"):
        # Mitsuba takes one environment emitter.
        sys.exit("reference.py: --sky with --sky-map has no Mitsuba counterpart here")
    if doc.get("sky"):
        d["sky"] = {"type": "constant", "radiance": {"type": "rgb", "value": doc["sky"]}}
    if doc.get("sky_map") and "sun_sky" in doc["sky_map"]:
        # --sun-sky is Mitsuba's sunsky (its sky Z-up: turned to Y-up) in
        # the renderer's units, its sun included.
        s = doc["sky_map"]["sun_sky"]
        d["sky"] = {"type": "sunsky", "sun_direction": s["toward"], "turbidity": s["turbidity"],
                    "albedo": s["albedo"], "sun_scale": s["scale"], "sky_scale": s["scale"],
                    "to_world": mi.ScalarTransform4f().rotate([1, 0, 0], -90)}
    elif doc.get("sky_map"):
        # The renderer's --sky-map convention is Mitsuba's envmap, turned
        # about +Y as its to_world rotation is.
        m = doc["sky_map"]
        d["sky"] = {"type": "envmap", "filename": m["path"], "scale": m["strength"],
                    "to_world": mi.ScalarTransform4f().rotate([0, 1, 0], m["rotation_degrees"])}
    if args.image:
        return render_image(mi, dr, d, doc["camera"], args)
    scene = mi.load_dict(d)
    integrator = mi.load_dict({"type": "path", "max_depth": -1})

    def batch(node, n, seed, texture=None):
        """n irradiance samples (RGB) at points on `node` (times the
        texture's reflectance there, for a textured node)."""
        tris = node["triangles"]
        areas = []
        for a, b, c in tris:
            u = [b[k] - a[k] for k in range(3)]
            v = [c[k] - a[k] for k in range(3)]
            cx = [u[1] * v[2] - u[2] * v[1], u[2] * v[0] - u[0] * v[2], u[0] * v[1] - u[1] * v[0]]
            areas.append(0.5 * math.sqrt(sum(x * x for x in cx)))
        total = sum(areas)
        cdf, acc = [], 0.0
        for a in areas:
            acc += a / total
            cdf.append(acc)
        sampler = mi.load_dict({"type": "independent"})
        sampler.seed(seed, n)
        # Pick a triangle by area (a table lookup in Dr.Jit), then a point in it.
        table = mi.Float(cdf)
        u0 = sampler.next_1d()
        idx = dr.binary_search(0, len(cdf) - 1, lambda k: dr.gather(mi.Float, table, k) < u0)
        corner = lambda j, axis: dr.gather(mi.Float, mi.Float([t[j][axis] for t in tris]), idx)
        A = mi.Point3f(corner(0, 0), corner(0, 1), corner(0, 2))
        B = mi.Point3f(corner(1, 0), corner(1, 1), corner(1, 2))
        C = mi.Point3f(corner(2, 0), corner(2, 1), corner(2, 2))
        bary = mi.warp.square_to_uniform_triangle(sampler.next_2d())
        p = A * (1 - bary.x - bary.y) + B * bary.x + C * bary.y
        nrm = dr.normalize(dr.cross(B - A, C - A))
        si = dr.zeros(mi.SurfaceInteraction3f)
        si.p, si.n = p, nrm
        si.sh_frame = mi.Frame3f(nrm)
        si.wi = mi.Vector3f(0, 0, 1)
        # Emitter sample, MIS-weighted against the cosine density.
        ds, em_w = scene.sample_emitter_direction(si, sampler.next_2d(), True)
        cos_e = dr.maximum(dr.dot(nrm, ds.d), 0.0)
        pdf_cos = cos_e / math.pi
        w_e = dr.select(ds.pdf > 0, dr.square(ds.pdf) / (dr.square(ds.pdf) + dr.square(pdf_cos)), 0.0)
        # A point or directional light cannot be hit by the cosine sample.
        w_e = dr.select(ds.delta, 1.0, w_e)
        direct = em_w * cos_e * w_e
        # Cosine sample: the path integrator's radiance along it, its first
        # hit's emission MIS-weighted against the emitter density.
        local = mi.warp.square_to_cosine_hemisphere(sampler.next_2d())
        dirn = si.sh_frame.to_world(local)
        ray = si.spawn_ray(dirn)
        L, _, _ = integrator.sample(scene, sampler, ray)
        hit = scene.ray_intersect(ray)
        # An escaping ray's emitter is the sky (Mitsuba's environment), if any.
        emitter = hit.emitter(scene)
        le = emitter.eval(hit)
        ds2 = mi.DirectionSample3f(scene, hit, si)
        pdf_em = scene.pdf_emitter_direction(si, ds2)
        pdf_b = local.z / math.pi
        w_b = dr.select(pdf_em > 0, dr.square(pdf_b) / (dr.square(pdf_b) + dr.square(pdf_em)), 1.0)
        indirect = (L - le + le * w_b) * math.pi
        e = direct + indirect
        if texture is not None:
            uv_of = lambda j, axis: dr.gather(mi.Float, mi.Float([t[j][axis] for t in node["uvs"]]), idx)
            w0 = 1 - bary.x - bary.y
            si.uv = mi.Point2f(
                uv_of(0, 0) * w0 + uv_of(1, 0) * bary.x + uv_of(2, 0) * bary.y,
                uv_of(0, 1) * w0 + uv_of(1, 1) * bary.x + uv_of(2, 1) * bary.y)
            e = e * texture.eval(si)
        dr.eval(e)
        return e

    if args.trace:
        # Compile the kernels before timing, as the renderer's device set-up
        # is left out of its solve time.
        for i, node in enumerate(nodes):
            dr.eval(batch(node, args.batch, 999_983 + i, textures.get(i)))
        print(json.dumps({"variant": mi.variant()}), flush=True)
    start = time.perf_counter()
    sums = [[0.0] * 3 for _ in nodes]
    sq = [0.0 for _ in nodes]  # of the RGB sum
    count = [0 for _ in nodes]
    done = [False for _ in nodes]
    seed = args.seed
    result = []
    while True:
        for i, node in enumerate(nodes):
            if done[i]:
                continue
            e = batch(node, args.batch, (seed * 1000003 + i) % (1 << 32), textures.get(i))  # Mitsuba's seed is a u32
            seed += 1
            r, g, b = (dr.sum(e.x)[0], dr.sum(e.y)[0], dr.sum(e.z)[0])
            # A textured node's samples carry their reflectance already.
            rho = [1.0, 1.0, 1.0] if i in textures else node["reflectance"]
            s = e.x * rho[0] + e.y * rho[1] + e.z * rho[2]
            sums[i][0] += r; sums[i][1] += g; sums[i][2] += b
            sq[i] += dr.sum(s * s)[0]
            count[i] += args.batch
        result = []
        worst = 0.0
        for i, node in enumerate(nodes):
            n = count[i]
            E = [x / n for x in sums[i]]
            rho, le = node["reflectance"], node["emission"]
            if i in textures:
                rho = [1.0, 1.0, 1.0]
            Bv = [rho[c] * E[c] + math.pi * le[c] for c in range(3)]
            mean_s = sum(rho[c] * E[c] for c in range(3))
            var = max(sq[i] / n - mean_s * mean_s, 0.0)
            se = math.sqrt(var / n)
            rel = se / max(sum(Bv), 1e-300)
            done[i] = rel <= args.target
            worst = max(worst, rel)
            result.append({"node": node["name"], "area": node["area"], "radiosity": Bv,
                           "standard_error": se, "relative_standard_error": rel})
        elapsed = time.perf_counter() - start
        print(f"reference: {max(count)} points per node, worst relative SE {worst:.2e}, {elapsed:.0f} s", file=sys.stderr)
        if args.trace:
            print(json.dumps({"points": max(count), "seconds": elapsed, "surfaces": result}), flush=True)
        if all(done) or elapsed > args.max_seconds:
            break
    if args.trace:
        return
    print(json.dumps({
        "how": f"Mitsuba 3 {mi.variant()}, next-event estimation + cosine sampling (MIS, power heuristic) at uniform points per node, path integrator beyond (scripts/reference.py --target {args.target})",
        "variant": mi.variant(), "seconds": time.perf_counter() - start,
        "converged": all(done), "surfaces": result}, indent=1))


def bitmap(mi, tex, args, tmp, name, cap):
    """A node's texture as a Mitsuba bitmap: the image as the renderer reads
    it (sRGB texels), or, where its factor is not 1, times its factor and at
    most `cap` (a reflectance's), baked into a linear image."""
    image = os.path.join(os.path.dirname(os.path.abspath(args.nodes)), tex["image"])
    raw = False
    if any(abs(f - 1.0) > 1e-6 for f in tex["factor"]):
        # The renderer multiplies the linear texel by the factor (capped
        # as a reflectance): bake that into a linear image.
        import numpy as np
        bmp = mi.Bitmap(image).convert(mi.Bitmap.PixelFormat.RGB,
                                       mi.Struct.Type.Float32, srgb_gamma=False)
        factor = np.array(tex["factor"][:3], dtype=np.float32)
        scaled = np.array(bmp) * factor
        if cap is not None:
            scaled = np.minimum(scaled, cap)
        image = os.path.join(tmp, f"{name}.exr")
        mi.Bitmap(scaled.astype(np.float32)).write(image)
        raw = True
    wrap = {"repeat": "repeat", "mirror": "mirror", "clamp": "clamp"}[tex["wrap"][0]]
    return {"type": "bitmap", "filename": image, "wrap_mode": wrap,
            "filter_type": "bilinear", "raw": raw}


def render_image(mi, dr, d, cam, args):
    """The camera image by path tracing, with per-block standard errors."""
    import numpy as np
    if args.height is None:
        args.height = max(1, round(args.width / (cam.get("aspect") or 1.0)))
    p, f, u = cam["position"], cam["forward"], cam["up"]
    target = [p[k] + f[k] for k in range(3)]
    d["sensor"] = {
        "type": "perspective", "fov_axis": "y", "fov": cam["yfov_degrees"],
        "near_clip": 1e-4, "far_clip": 1e6,
        "to_world": mi.ScalarTransform4f().look_at(origin=p, target=target, up=u),
        "film": {"type": "hdrfilm", "width": args.width, "height": args.height,
                 "rfilter": {"type": "box"}, "pixel_format": "rgb"},
        "sampler": {"type": "independent", "sample_count": max(args.spp // args.passes, 1)},
    }
    d["integrator"] = {"type": "path", "max_depth": -1}
    scene = mi.load_dict(d)
    start = time.perf_counter()
    passes = []
    for k in range(args.passes):
        img = np.array(mi.render(scene, seed=args.seed * 7919 + k), dtype=np.float64)[:, :, :3]
        passes.append(img)
        print(f"reference image: pass {k + 1}/{args.passes}, {time.perf_counter() - start:.0f} s", file=sys.stderr)
    stack = np.stack(passes)
    mean = stack.mean(axis=0)
    h, w = args.height // 4 * 4, args.width // 4 * 4
    blocks = stack[:, :h, :w, :].reshape(args.passes, h // 4, 4, w // 4, 4, 3).mean(axis=(2, 4))
    bmean = blocks.mean(axis=0)
    bse = blocks.std(axis=0, ddof=1) / math.sqrt(args.passes)
    rel = (bse.sum(axis=2) / np.maximum(bmean.sum(axis=2), 1e-30))
    mi.Bitmap(mean.astype(np.float32)).write(args.image)
    meta = {
        "how": f"Mitsuba 3 {mi.variant()} path integrator (next-event estimation, MIS), box filter, "
               f"{args.spp} samples per pixel in {args.passes} passes",
        "command": "scripts/reference.py " + " ".join(sys.argv[1:]),
        "size": [args.width, args.height],
        "seconds": time.perf_counter() - start,
        "block_relative_standard_error": {"median": float(np.median(rel)), "max": float(rel.max())},
    }
    with open(os.path.splitext(args.image)[0] + ".json", "w") as out:
        json.dump(meta, out, indent=1)
    print(json.dumps(meta), file=sys.stderr)


if __name__ == "__main__":
    main()
