#!/usr/bin/env python3
"""The oracle for vdbcook's FLIP figures (crates/validate/src/flip.rs).

Builds the same synthetic 8-bit sRGB image pairs as the Rust test
`flip_matches_the_reference_implementation` (integer arithmetic, so both make
the same bytes) and prints the mean LDR-FLIP error of each at 67 pixels per
degree, computed by NVIDIA's FLIP from PyPI (`pip install flip-evaluator`).
With two PNG paths it prints the mean FLIP of that pair instead.
"""
import sys

import numpy as np
import flip_evaluator


def pair(case):
    w, h = 96, 64
    ref = np.zeros((h, w, 3), np.uint8)
    test = np.zeros((h, w, 3), np.uint8)
    lcg = 12345
    for y in range(h):
        for x in range(w):
            d2 = (x - 40) ** 2 + (y - 30) ** 2
            blob = max(200 - d2 // 2, 0)
            px = [min(x * 255 // (w - 1) + blob, 255), min(y * 255 // (h - 1), 255), min(blob + 30, 255)]
            q = list(px)
            if case == 1:
                q = [max(v - 12, 0) for v in px]
            elif case == 2 and 48 <= x < 64 and 16 <= y < 32:
                q = [128, 128, 128]
            elif case == 3:
                for i in range(3):
                    lcg = (lcg * 1664525 + 1013904223) & 0xFFFFFFFF
                    q[i] = min(max(q[i] + ((lcg >> 24) % 17) - 8, 0), 255)
            ref[y, x] = px
            test[y, x] = q
    return ref, test


def mean_flip(ref, test):
    _, mean, _ = flip_evaluator.evaluate(ref.astype(np.float32) / 255.0, test.astype(np.float32) / 255.0, "LDR", parameters={"ppd": 67.0})
    return mean


if __name__ == "__main__":
    if len(sys.argv) == 3:
        print(f"{flip_evaluator.evaluate(sys.argv[1], sys.argv[2], 'LDR', applyMagma=False, parameters={'ppd': 67.0})[1]:.8f}")
    else:
        for case in (1, 2, 3):
            print(f"case {case}: {mean_flip(*pair(case)):.8f}")
