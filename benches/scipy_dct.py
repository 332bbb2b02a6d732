#!/usr/bin/env python3
"""Baseline for `photostereo integrate --method dct`: Simchony-Chellappa DCT Poisson solve.

    python3 scipy_dct.py normals.npy depth.npy

Reads an (H, W, 3) float normal map in photostereo's frame (x right, y up, z to the viewer),
takes p = -nx/nz, q = ny/nz (row index grows downward), solves the Neumann Poisson equation of
the trapezoid edge targets by DCT-II and writes the zero-mean depth (H, W) float32 in pixels.
"""
import sys
import numpy as np
from scipy.fft import dctn, idctn

n = np.load(sys.argv[1]).astype(np.float64)
nz = np.maximum(n[..., 2], 1e-3)
p, q = np.clip(-n[..., 0] / nz, -20, 20), np.clip(n[..., 1] / nz, -20, 20)
dh, dv = 0.5 * (p[:, :-1] + p[:, 1:]), 0.5 * (q[:-1] + q[1:])  # edge targets
b = np.zeros_like(p)  # right-hand side of the normal equations (graph Laplacian, Neumann)
b[:, :-1] -= dh; b[:, 1:] += dh; b[:-1] -= dv; b[1:] += dv
h, w = b.shape
e = (2 - 2 * np.cos(np.pi * np.arange(h) / h))[:, None] + (2 - 2 * np.cos(np.pi * np.arange(w) / w))[None, :]
e[0, 0] = 1.0
f = dctn(b, type=2, norm="ortho") / e
f[0, 0] = 0.0
np.save(sys.argv[2], idctn(f, type=2, norm="ortho").astype(np.float32))
