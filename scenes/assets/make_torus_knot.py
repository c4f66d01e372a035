#!/usr/bin/env python3
"""Writes torus_knot.obj: a (2, 3) torus knot tube with smooth normals and UVs.

Run from this folder: python3 make_torus_knot.py [segments] [sides]. The committed
file was made with the defaults (240 x 16: 7 680 triangles).
"""
import math
import sys

segments = int(sys.argv[1]) if len(sys.argv) > 1 else 240
sides = int(sys.argv[2]) if len(sys.argv) > 2 else 16
p, q, radius, tube = 2, 3, 1.0, 0.28


def curve(t):
    r = radius * (2 + math.cos(q * t)) / 3
    return (r * math.cos(p * t), radius * math.sin(q * t) / 3 * 1.2, r * math.sin(p * t))


def sub(a, b):
    return (a[0] - b[0], a[1] - b[1], a[2] - b[2])


def cross(a, b):
    return (a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0])


def norm(a):
    n = math.sqrt(a[0] ** 2 + a[1] ** 2 + a[2] ** 2)
    return (a[0] / n, a[1] / n, a[2] / n)


lines = ["# (2, 3) torus knot, made by make_torus_knot.py"]
normals = []
for i in range(segments):
    t = 2 * math.pi * i / segments
    c = curve(t)
    tangent = norm(sub(curve(t + 1e-4), curve(t - 1e-4)))
    side = norm(cross(tangent, (0.0, 1.0, 0.0)))
    up = cross(side, tangent)
    for j in range(sides):
        a = 2 * math.pi * j / sides
        n = tuple(math.cos(a) * side[k] + math.sin(a) * up[k] for k in range(3))
        v = tuple(c[k] + tube * n[k] for k in range(3))
        lines.append("v %.6f %.6f %.6f" % v)
        normals.append("vn %.6f %.6f %.6f" % n)
lines += normals
for i in range(segments + 1):
    for j in range(sides + 1):
        lines.append("vt %.6f %.6f" % (i / segments, j / sides))
for i in range(segments):
    for j in range(sides):
        a = i * sides + j
        b = ((i + 1) % segments) * sides + j
        c = ((i + 1) % segments) * sides + (j + 1) % sides
        d = i * sides + (j + 1) % sides
        ta = i * (sides + 1) + j
        tb = (i + 1) * (sides + 1) + j
        tc = (i + 1) * (sides + 1) + j + 1
        td = i * (sides + 1) + j + 1
        lines.append("f %d/%d/%d %d/%d/%d %d/%d/%d" % (a + 1, ta + 1, a + 1, b + 1, tb + 1, b + 1, c + 1, tc + 1, c + 1))
        lines.append("f %d/%d/%d %d/%d/%d %d/%d/%d" % (a + 1, ta + 1, a + 1, c + 1, tc + 1, c + 1, d + 1, td + 1, d + 1))
with open("torus_knot.obj", "w") as f:
    f.write("\n".join(lines) + "\n")
