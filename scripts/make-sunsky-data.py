#!/usr/bin/env python3
"""Writes src/scene/sunsky/hosek-wilkie-rgb.bin, the tables `--sun-sky`
evaluates, from the Hosek-Wilkie datasets Mitsuba 3 ships (3-clause BSD,
Lukas Hosek and Alexander Wilkie; the notice is in
src/scene/sunsky/LICENSE-hosek-wilkie.txt):

1. the sky's RGB parameters, [turbidity 1..10][albedo 0, 1][6 Bezier control
   points over elevation][R, G, B][9], as Mitsuba's `sky_params_rgb`;
2. the sky's RGB radiance scale, [10][2][6][3], as `sky_rad_rgb`;
3. the sun's irradiance (W/m^2 per channel, in the sky's units) on a surface
   facing it, [turbidity 1..10][elevation 0, 0.5, ... 90 degrees][3]: Mitsuba's
   `sunsky` sun (its 0.5358-degree disc, limb darkened) integrated over the
   disc, times UNIT.

Little-endian f64, in that order. The sky's units are those of the
datasets (luminance-equivalent W sr^-1 m^-2: times 683 lm/W it is cd/m^2);
Mitsuba divides them by UNIT, so `--sun-sky` is Mitsuba's `sunsky` with
`sun_scale` and `sky_scale` UNIT (checked by scripts/reference.py's users).

    DRJIT_LIBLLVM_PATH=/usr/lib/x86_64-linux-gnu/libLLVM-19.so \
        python3 scripts/make-sunsky-data.py
"""
import math
import os

import numpy as np

UNIT = 106.7505
APERTURE = 0.5358  # degrees, Mitsuba's default sun


def datasets():
    import mitsuba as mi
    path = os.path.join(os.path.dirname(mi.__file__), "data", "sunsky",
                        "sunsky_datasets.bin")
    raw = open(path, "rb").read()
    # Offsets as the file's own header lists them (mi.TensorFile prints it).
    rad = np.frombuffer(raw, "<f8", 10 * 2 * 6 * 3, 418555)
    params = np.frombuffer(raw, "<f8", 10 * 2 * 6 * 3 * 9, 421435)
    return params, rad


def sun_irradiance(turbidity, elevation, radial=1024, around=32):
    """Mitsuba's sun, integrated over its disc, in the sky's units."""
    import mitsuba as mi
    import drjit as dr
    e = math.radians(elevation)
    s = np.array([0.0, math.cos(e), math.sin(e)])  # Mitsuba's sky is Z-up
    em = mi.load_dict({"type": "sunsky", "sun_direction": list(s),
                       "turbidity": float(turbidity), "albedo": 0.3,
                       "sky_scale": 0.0, "sun_aperture": APERTURE})
    r = math.radians(APERTURE / 2)
    u = np.cross(s, [1.0, 0.0, 0.0])
    u /= np.linalg.norm(u)
    v = np.cross(s, u)
    # Equal-area rings over the disc, their points spread around each.
    i, j = np.meshgrid((np.arange(radial) + 0.5) / radial,
                       (np.arange(around) + 0.5) / around, indexing="ij")
    rho = (2 * np.arcsin(np.sqrt(i) * math.sin(r / 2))).ravel()
    phi = (2 * math.pi * j).ravel()
    d = (np.cos(rho)[:, None] * s + np.sin(rho)[:, None]
         * (np.cos(phi)[:, None] * u + np.sin(phi)[:, None] * v))
    si = dr.zeros(mi.SurfaceInteraction3f, len(rho))
    si.wi = -mi.Vector3f(d[:, 0], d[:, 1], d[:, 2])
    radiance = em.eval(si)
    radiance = np.array([np.array(radiance[c]) for c in range(3)])
    solid = 2 * math.pi * (1 - math.cos(r))
    e = (radiance * np.cos(rho)).mean(axis=1) * solid * UNIT
    return np.maximum(e, 0.0)


def main():
    import mitsuba as mi
    mi.set_variant("llvm_ad_rgb")
    params, rad = datasets()
    # Mitsuba's sun is black with its centre exactly on the horizon and
    # not just above it: the first row is taken just above.
    sun = np.array([[sun_irradiance(t, max(k / 2, 1e-3)) for k in range(181)]
                    for t in range(1, 11)])
    out = os.path.join(os.path.dirname(__file__), "..", "src", "scene",
                       "sunsky", "hosek-wilkie-rgb.bin")
    data = np.concatenate([params, rad, sun.ravel()]).astype("<f8")
    tmp = out + ".tmp"
    data.tofile(tmp)
    os.replace(tmp, out)
    print(f"wrote {out}: {len(data)} values; sun at 45 degrees, T 3: {sun[2, 90]}")


if __name__ == "__main__":
    main()
