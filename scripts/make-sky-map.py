#!/usr/bin/env python3
"""Writes the generated sky maps the references and the README use:
equirectangular, linear radiance (W sr^-1 m^-2), +Y up, oriented as
Mitsuba's envmap (the renderer's --sky-map convention).

  window-sun: a sky brighter toward the zenith (0.6 + 0.8 y), a ground of
    0.3, and a sun of irradiance 20 W/m^2 (a Gaussian 2 degrees wide) toward
    -1,0.9,0.3: the light family-furnished-N carries, as a map.
  courtyard: a sky of 20 and a sun of 1000 W/m^2 toward 0.2,1,0.3, as
    Sponza's --sun 0.2,1,0.3,1000 --sky 20, with a ground of 2.

Usage: scripts/make-sky-map.py OUT_DIR   (needs numpy and mitsuba)
"""
import math
import os
import sys

import mitsuba as mi
import numpy as np

mi.set_variant("scalar_rgb")


def directions(w, h):
    """Each texel's centre direction, in the renderer's convention."""
    phi = (np.arange(w) + 0.5) / w * 2 * math.pi
    theta = (np.arange(h) + 0.5) / h * math.pi
    p, t = np.meshgrid(phi, theta)
    return np.stack([np.sin(p) * np.sin(t), np.cos(t), -np.cos(p) * np.sin(t)], -1), t


def sky(w, h, zenith, horizon, ground, sun, irradiance, width_deg=2.0):
    d, theta = directions(w, h)
    y = d[..., 1]
    l = np.where(y > 0, horizon + (zenith - horizon) * y, ground)
    s = np.array(sun, dtype=np.float64)
    s /= np.linalg.norm(s)
    ang = np.arccos(np.clip(d @ s, -1, 1))
    sigma = math.radians(width_deg)
    g = np.exp(-0.5 * (ang / sigma) ** 2)
    # Scale the spot so its irradiance on a surface facing it is exact over
    # the texels (solid angle per row, cosine to the sun).
    solid = (np.cos(np.arange(h) / h * math.pi) - np.cos((np.arange(h) + 1) / h * math.pi)) * 2 * math.pi / w
    e = (g * np.clip(d @ s, 0, None) * solid[:, None]).sum()
    l = l + g * irradiance / e
    return np.repeat(l[..., None], 3, -1).astype(np.float32)


def main():
    out = sys.argv[1] if len(sys.argv) > 1 else "docs/references/maps"
    os.makedirs(out, exist_ok=True)
    maps = {
        "window-sun": sky(512, 256, 1.4, 0.6, 0.3, (-1, 0.9, 0.3), 20.0),
        "courtyard": sky(512, 256, 20.0, 20.0, 2.0, (0.2, 1, 0.3), 1000.0),
    }
    for name, texels in maps.items():
        path = os.path.join(out, f"{name}.exr")
        mi.Bitmap(texels).write(path)
        print(f"wrote {path}")


if __name__ == "__main__":
    main()
