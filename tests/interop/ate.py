"""Independent ATE: associate TUM poses by timestamp (max 0.01 s), align with Umeyama (SE(3), no scale) in numpy,
print the translation RMSE. Mirrors what `evo_ape tum gt est -a` computes. With a third argument `--scale`, the
Umeyama similarity instead (`evo_ape -as`): prints the RMSE and the estimate's size over the truth's."""
import sys

import numpy as np


def load(path):
    data = np.loadtxt(path, comments="#", ndmin=2)
    return data[:, 0], data[:, 1:4]


def main(gt_path, est_path, with_scale=False):
    tg, pg = load(gt_path)
    te, pe = load(est_path)
    pairs, used = [], set()
    for j, t in enumerate(te):
        i = int(np.argmin(np.abs(tg - t)))
        if abs(tg[i] - t) <= 0.01 and i not in used:
            used.add(i)
            pairs.append((i, j))
    dst = np.array([pg[i] for i, _ in pairs])
    src = np.array([pe[j] for _, j in pairs])
    ms, md = src.mean(axis=0), dst.mean(axis=0)
    cov = (dst - md).T @ (src - ms) / len(src)
    u, d, vt = np.linalg.svd(cov)
    s = np.eye(3)
    if np.linalg.det(u @ vt) < 0:
        s[2, 2] = -1
    r = u @ s @ vt
    c = np.trace(np.diag(d) @ s) / np.mean(np.sum((src - ms) ** 2, axis=1)) if with_scale else 1.0
    t = md - c * r @ ms
    err = np.linalg.norm(dst - (c * src @ r.T + t), axis=1)
    if with_scale:
        print(f"{np.sqrt(np.mean(err ** 2)):.12e} {1.0 / c:.12e}")
    else:
        print(f"{np.sqrt(np.mean(err ** 2)):.12e}")


if __name__ == "__main__":
    main(sys.argv[1], sys.argv[2], len(sys.argv) > 3 and sys.argv[3] == "--scale")
