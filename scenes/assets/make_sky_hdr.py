#!/usr/bin/env python3
"""Writes sky.hdr: a small equirectangular sky for scenes/environment.toml (Radiance RGBE,
flat scanlines, no dependencies). A blue gradient sky with a small bright sun, a hazy
horizon and a brown ground; the sun is what importance sampling must find.

Run from this folder: python3 make_sky_hdr.py (the committed sky.hdr is its output)."""

import math

W, H = 128, 64
SUN = (math.radians(35.0), math.radians(40.0))  # elevation, azimuth from -z towards +x
SUN_RADIUS = math.radians(4.0)
SUN_RADIANCE = 400.0


def direction(u, v):
    # The renderer's mapping: u = 1/2 + atan2(x, -z) / 2pi, v = theta / pi from +y.
    theta, phi = v * math.pi, (u - 0.5) * 2.0 * math.pi
    return (math.sin(theta) * math.sin(phi), math.cos(theta), -math.sin(theta) * math.cos(phi))


def radiance(d):
    el, az = SUN
    sun = (math.cos(el) * math.sin(az), math.sin(el), -math.cos(el) * math.cos(az))
    if sum(a * b for a, b in zip(d, sun)) > math.cos(SUN_RADIUS):
        return (SUN_RADIANCE, SUN_RADIANCE * 0.9, SUN_RADIANCE * 0.75)
    y = d[1]
    if y < 0.0:
        return (0.25, 0.18, 0.12)
    haze = math.exp(-8.0 * y)
    return (0.25 + 0.6 * haze, 0.45 + 0.45 * haze, 1.0 + 0.1 * haze)


def rgbe(c):
    m = max(c)
    if m < 1e-32:
        return bytes(4)
    e = math.frexp(m)[1]
    s = 256.0 / 2.0**e
    return bytes([min(255, int(c[0] * s)), min(255, int(c[1] * s)), min(255, int(c[2] * s)), e + 128])


def main():
    out = bytearray(b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n")
    out += f"-Y {H} +X {W}\n".encode()
    for y in range(H):
        for x in range(W):
            out += rgbe(radiance(direction((x + 0.5) / W, (y + 0.5) / H)))
    with open("sky.hdr", "wb") as f:
        f.write(out)


if __name__ == "__main__":
    main()
