#!/usr/bin/env python3
"""A synthetic SIZE x SIZE normal map (float32 (H, W, 3), photostereo's camera frame) of the
smooth analytic surface f(x, y) = A sin(2 pi x / L) cos(2 pi y / L) + B exp(-r^2 / s^2), with
its exact depth (zero mean, pixels) beside it.

    python3 make_normals.py SIZE normals.npy [depth_truth.npy]
"""
import sys
import numpy as np

s = int(sys.argv[1])
r, c = np.mgrid[0:s, 0:s].astype(np.float64)
L, A, B, S = s / 3.0, s / 40.0, s / 8.0, s / 4.0
x, y = c - s / 2, r - s / 2
f = A * np.sin(2 * np.pi * c / L) * np.cos(2 * np.pi * r / L) + B * np.exp(-(x * x + y * y) / S**2)
fc = A * 2 * np.pi / L * np.cos(2 * np.pi * c / L) * np.cos(2 * np.pi * r / L) - 2 * x / S**2 * B * np.exp(-(x * x + y * y) / S**2)
fr = -A * 2 * np.pi / L * np.sin(2 * np.pi * c / L) * np.sin(2 * np.pi * r / L) - 2 * y / S**2 * B * np.exp(-(x * x + y * y) / S**2)
# p = df/dcol = -nx/nz, q = df/drow = ny/nz  ->  n ~ (-p, q, 1)
n = np.stack([-fc, fr, np.ones_like(f)], axis=-1)
n /= np.linalg.norm(n, axis=-1, keepdims=True)
np.save(sys.argv[2], n.astype(np.float32))
if len(sys.argv) > 3:
    np.save(sys.argv[3], (f - f.mean()).astype(np.float32))
