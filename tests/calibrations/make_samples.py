#!/usr/bin/env python3
"""Writes one stereo calibration in every layout bdis-slam reads, from the data sets' published layouts
(numpy only). tests/calibration_formats.rs checks that each reads to the same cameras and rectification.

The rig: a 1280x1024 stereo endoscope, 5 mm baseline, the right camera turned by ~0.75 deg, a wide lens with the
8-coefficient rational distortion (k1 k2 p1 p2 k3 k4 k5 k6). Hamlyn's files carry 5 coefficients (k1 k2 p1 p2 k3),
so its sample is the same rig with k4 = k5 = k6 = 0; SERV-CT's is already rectified (its own P1, P2)."""
import json
import os

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
W, H = 1280, 1024
K1 = np.array([[780.25, 0.0, 641.3], [0.0, 781.5, 509.75], [0.0, 0.0, 1.0]])
K2 = np.array([[779.125, 0.0, 637.875], [0.0, 780.375, 512.25], [0.0, 0.0, 1.0]])
D1 = [-0.31, 0.12, 0.0008, -0.0005, -0.02, 0.05, 0.01, -0.003]
D2 = [-0.30, 0.11, -0.0004, 0.0006, -0.018, 0.048, 0.012, -0.002]
OM = np.array([0.004, -0.012, 0.0025])
T = np.array([-4.98, 0.03, -0.05])


def rodrigues(om):
    theta = np.linalg.norm(om)
    k = om / theta
    kx = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + np.sin(theta) * kx + (1 - np.cos(theta)) * kx @ kx


R = rodrigues(OM)


def write(path, text):
    full = os.path.join(HERE, path)
    os.makedirs(os.path.dirname(full), exist_ok=True)
    with open(full, "w") as f:
        f.write(text)


def num(v):
    return repr(float(v))


def cv_matrix(name, m):
    m = np.atleast_2d(m)
    data = ", ".join(num(v) for v in m.ravel())
    return f"{name}: !!opencv-matrix\n   rows: {m.shape[0]}\n   cols: {m.shape[1]}\n   dt: d\n   data: [ {data} ]\n"


def scared(d1, d2):
    return ("%YAML:1.0\n---\n" + cv_matrix("R", R) + cv_matrix("T", T.reshape(3, 1)) + cv_matrix("M1", K1)
            + cv_matrix("D1", np.array(d1)) + cv_matrix("M2", K2) + cv_matrix("D2", np.array(d2))
            + f"width: {W}\nheight: {H}\n")


# SCARED: OpenCV FileStorage YAML, M1 D1 M2 D2 R T.
write("scared/endoscope_calibration.yaml", scared(D1, D2))
write("scared/endoscope_calibration_5.yaml", scared(D1[:5], D2[:5]))

# StereoMIS StereoCalibration.ini: a section per camera; the right camera's pose under [StereoRight].
lines = []
for section, k, d, r, t in (("StereoLeft", K1, D1, np.eye(3), np.zeros(3)), ("StereoRight", K2, D2, R, T)):
    lines.append(f"[{section}]")
    lines += [f"res_x = {W}", f"res_y = {H}", f"fc_x = {num(k[0, 0])}", f"fc_y = {num(k[1, 1])}",
              f"cc_x = {num(k[0, 2])}", f"cc_y = {num(k[1, 2])}"]
    lines += [f"kc_{i} = {num(v)}" for i, v in enumerate(d)]
    lines += [f"R_{i} = {num(v)}" for i, v in enumerate(r.ravel())]
    lines += [f"T_{i} = {num(v)}" for i, v in enumerate(t)]
    lines.append("")
write("stereomis/StereoCalibration.ini", "\n".join(lines))

# StereoMIS camcal.json: intrinsics f, c, k per camera; extrinsics as a Rodrigues vector om and T.
camcal = {"data": {
    "width": W, "height": H,
    "intrinsics": [{"f": [K1[0, 0], K1[1, 1]], "c": [K1[0, 2], K1[1, 2]], "k": D1},
                   {"f": [K2[0, 0], K2[1, 1]], "c": [K2[0, 2], K2[1, 2]], "k": D2}],
    "extrinsics": {"om": OM.tolist(), "T": T.tolist()},
}}
write("stereomis/camcal.json", json.dumps(camcal, indent=2) + "\n")

# Hamlyn: K (three rows) then the distortion row per camera; the extrinsic file R (three rows) then T.
def rows(m):
    return "".join(" ".join(num(v) for v in row) + "\n" for row in np.atleast_2d(m))


write("hamlyn/Left_Camera_Calibration_Intrinsic.txt", rows(K1) + rows(np.array(D1[:5])))
write("hamlyn/Right_Camera_Calibration_Intrinsic.txt", rows(K2) + rows(np.array(D2[:5])))
write("hamlyn/camera_extrinsic.txt", rows(R) + rows(T))

# SERV-CT: a rectified pair's projections as OpenCV JSON matrices.
f, cx, cy = 770.0, 640.5, 511.0
P1 = np.array([[f, 0, cx, 0], [0, f, cy, 0], [0, 0, 1, 0]])
P2 = np.array([[f, 0, cx, f * -4.985], [0, f, cy, 0], [0, 0, 1, 0]])
Q = np.array([[1, 0, 0, -cx], [0, 1, 0, -cy], [0, 0, 0, f], [0, 0, 1 / 4.985, 0]])
mat = lambda m: {"type_id": "opencv-matrix", "rows": m.shape[0], "cols": m.shape[1], "dt": "d",
                 "data": m.ravel().tolist()}
write("servct/Rectified_calibration_001.json", json.dumps({"P1": mat(P1), "P2": mat(P2), "Q": mat(Q)}, indent=2) + "\n")
