#!/usr/bin/env python3
"""Golden check of bdis-slam's rectification against OpenCV (opencv-python, a CI-only cross-check; the product
has no OpenCV). For several calibrations — mild 5-coefficient distortion, a strong 8-coefficient rational one,
a vertical rig, a 1280x1024 one — written with cv2.FileStorage, and each alpha (unset, 0, 0.5, 1):
  - `bdis-slam calib show --json`: R1 R2 P1 P2 Q against cv2.stereoRectify(CALIB_ZERO_DISPARITY) within 0.01 px
    (rotations within 1e-9);
  - `--maps`: the exact undistort-rectify maps against cv2.initUndistortRectifyMap within 0.01 px wherever the
    source point lies in the image;
then an ORB-SLAM2 settings file with LEFT/RIGHT blocks (the rectification given), and `bdis-slam rectify` of
a textured pair against cv2.remap(INTER_LINEAR) within one grey level.

usage: rectify_golden.py BDIS_SLAM WORK_DIR
"""
import json, os, subprocess, sys
import numpy as np
import cv2

exe, work = sys.argv[1], sys.argv[2]
os.makedirs(work, exist_ok=True)
failures = []


def rodrigues(v):
    return cv2.Rodrigues(np.array(v, dtype=np.float64))[0]


def write_opencv(path, K1, D1, K2, D2, R, T, size=None):
    fs = cv2.FileStorage(path, cv2.FILE_STORAGE_WRITE)
    for k, v in [("M1", K1), ("D1", D1.reshape(1, -1)), ("M2", K2), ("D2", D2.reshape(1, -1)), ("R", R), ("T", T.reshape(3, 1))]:
        fs.write(k, v)
    if size:
        fs.write("width", size[0])
        fs.write("height", size[1])
    fs.release()


def pfm(path):
    with open(path, "rb") as f:
        kind = f.readline().strip()
        w, h = map(int, f.readline().split())
        scale = float(f.readline())
        data = np.frombuffer(f.read(), dtype="<f4" if scale < 0 else ">f4")
    assert kind == b"Pf", kind
    return data.reshape(h, w)[::-1]


def check(name, ok, detail):
    print(f"{'ok  ' if ok else 'FAIL'} {name}: {detail}")
    if not ok:
        failures.append(name)


K1 = np.array([[520.0, 0, 318.2], [0, 522.5, 241.7], [0, 0, 1]])
K2 = np.array([[515.3, 0, 325.1], [0, 517.9, 236.4], [0, 0, 1]])
R = rodrigues([0.01, -0.02, 0.005])
cases = [
    ("mild", K1, np.array([-0.10, 0.05, 0.001, -0.001, 0.0]), K2, np.array([-0.12, 0.07, -0.0005, 0.0008, -0.01]), (640, 480), R, np.array([-5.0, 0.1, 0.05])),
    ("rational8", K1, np.array([-0.35, 0.12, 0.001, -0.001, -0.02, 0.05, 0.01, 0.002]), K2, np.array([-0.30, 0.10, 0.0, 0.001, -0.01, 0.04, 0.0, 0.001]), (640, 480), R, np.array([-5.0, 0.1, 0.05])),
    ("vertical", K1, np.array([-0.10, 0.05, 0, 0, 0]), K2, np.array([-0.10, 0.04, 0, 0, 0]), (640, 480), rodrigues([0.02, 0.01, -0.01]), np.array([0.2, -4.0, 0.1])),
    ("scared-like 1280x1024", np.array([[1035.3, 0, 597.0], [0, 1035.1, 520.2], [0, 0, 1]]), np.array([-0.0006, 0.0017, 0.0, 0.0, 0.0]),
     np.array([[1035.3, 0, 688.9], [0, 1035.1, 520.2], [0, 0, 1]]), np.array([-0.0006, 0.0017, 0.0, 0.0, 0.0]), (1280, 1024), rodrigues([0.0, 0.0, 0.0]), np.array([-4.2, 0.0, 0.0])),
]

for name, K1, D1, K2, D2, size, R, T in cases:
    path = os.path.join(work, f"{name.split()[0]}.yaml")
    write_opencv(path, K1, D1, K2, D2, R, T, size if name == "mild" else None)
    for alpha in [None, 0.0, 0.5, 1.0]:
        maps_dir = os.path.join(work, f"maps-{name.split()[0]}-{alpha}")
        cmd = [exe, "calib", "show", path, "--json", "--maps", maps_dir]
        if name != "mild":
            cmd += ["--size", f"{size[0]}x{size[1]}"]
        if alpha is not None:
            cmd += ["--alpha", str(alpha)]
        out = subprocess.run(cmd, capture_output=True, text=True)
        if out.returncode != 0:
            check(f"{name} alpha {alpha}", False, out.stderr.strip())
            continue
        ours = json.loads(out.stdout)
        R1, R2, P1, P2, Q, _, _ = cv2.stereoRectify(K1, D1.reshape(1, -1), K2, D2.reshape(1, -1), size, R, T.reshape(3, 1),
                                                     flags=cv2.CALIB_ZERO_DISPARITY, alpha=-1 if alpha is None else alpha)
        rot = max(np.abs(np.array(ours["R1"]) - R1).max(), np.abs(np.array(ours["R2"]) - R2).max())
        proj = max(np.abs(np.array(ours["P1"]) - P1).max(), np.abs(np.array(ours["P2"])[:, :3] - P2[:, :3]).max())
        tx = np.abs(np.array(ours["P2"])[:, 3] - P2[:, 3]).max() / max(abs(P2[0, 0]), 1)
        q = np.abs(np.array(ours["Q"]) - Q).max()
        check(f"{name} alpha {alpha}: R1 R2", rot < 1e-9, f"max |Δ| {rot:.1e}")
        check(f"{name} alpha {alpha}: P1 P2", proj < 0.01 and tx < 1e-6, f"max |Δ| {proj:.1e} px, baseline column {tx:.1e}")
        check(f"{name} alpha {alpha}: Q", q < 1e-3, f"max |Δ| {q:.1e}")
        for side, (K, D, Rk, Pk) in [("left", (K1, D1, R1, P1)), ("right", (K2, D2, R2, P2))]:
            mx, my = cv2.initUndistortRectifyMap(K, D.reshape(1, -1), Rk, Pk, size, cv2.CV_32FC1)
            ox, oy = pfm(os.path.join(maps_dir, f"{side}_map_x.pfm")), pfm(os.path.join(maps_dir, f"{side}_map_y.pfm"))
            inside = (mx >= 0) & (my >= 0) & (mx <= size[0] - 1) & (my <= size[1] - 1)
            err = np.hypot(ox - mx, oy - my)[inside]
            check(f"{name} alpha {alpha}: {side} map", inside.mean() > 0.3 and err.max() < 0.01,
                  f"max {err.max():.1e} px over {inside.mean() * 100:.0f} % of the pixels")

# ORB-SLAM2 settings with LEFT/RIGHT blocks: the rectification is used as given.
name, K1, D1, K2, D2, size, R, T = cases[0]
R1, R2, P1, P2, Q, _, _ = cv2.stereoRectify(K1, D1.reshape(1, -1), K2, D2.reshape(1, -1), size, R, T.reshape(3, 1), flags=cv2.CALIB_ZERO_DISPARITY, alpha=0)
orb = os.path.join(work, "orbslam2.yaml")
# cv2.FileStorage refuses dotted keys, so the file is written as ORB-SLAM2's are: by hand.
def matrix(key, m):
    m = np.atleast_2d(m)
    data = ", ".join(repr(float(v)) for v in m.ravel())
    return f"{key}: !!opencv-matrix\n   rows: {m.shape[0]}\n   cols: {m.shape[1]}\n   dt: d\n   data: [ {data} ]\n"
with open(orb, "w") as f:
    f.write("%YAML:1.0\n")
    for side, K, D, Rk, Pk in [("LEFT", K1, D1, R1, P1), ("RIGHT", K2, D2, R2, P2)]:
        f.write(f"{side}.height: {size[1]}\n{side}.width: {size[0]}\n")
        f.write(matrix(f"{side}.D", D.reshape(1, -1)) + matrix(f"{side}.K", K) + matrix(f"{side}.R", Rk) + matrix(f"{side}.P", Pk))
maps_dir = os.path.join(work, "maps-orbslam2")
out = subprocess.run([exe, "calib", "show", orb, "--json", "--maps", maps_dir], capture_output=True, text=True)
if out.returncode != 0:
    check("ORB-SLAM2 LEFT/RIGHT", False, out.stderr.strip())
else:
    ours = json.loads(out.stdout)
    d = max(np.abs(np.array(ours["P2"]) - P2).max(), np.abs(np.array(ours["R1"]) - R1).max())
    check("ORB-SLAM2 LEFT/RIGHT: R, P as given", d < 1e-9, f"max |Δ| {d:.1e}")
    mx, my = cv2.initUndistortRectifyMap(K2, D2.reshape(1, -1), R2, P2, size, cv2.CV_32FC1)
    ox, oy = pfm(os.path.join(maps_dir, "right_map_x.pfm")), pfm(os.path.join(maps_dir, "right_map_y.pfm"))
    inside = (mx >= 0) & (my >= 0) & (mx <= size[0] - 1) & (my <= size[1] - 1)
    err = np.hypot(ox - mx, oy - my)[inside]
    check("ORB-SLAM2 LEFT/RIGHT: right map", err.max() < 0.01, f"max {err.max():.1e} px")

# `bdis-slam rectify` of a textured pair against cv2.remap (bilinear, 5-bit fixed point, black outside).
rng = np.random.default_rng(7)
seq = os.path.join(work, "raw")
for side in ("left", "right"):
    os.makedirs(os.path.join(seq, side), exist_ok=True)
    noise = rng.integers(0, 256, size=(size[1] // 8 + 1, size[0] // 8 + 1, 3), dtype=np.uint8)
    img = cv2.resize(noise, (size[0], size[1]), interpolation=cv2.INTER_CUBIC)
    cv2.imwrite(os.path.join(seq, side, "1.png"), img)
with open(os.path.join(seq, "times.txt"), "w") as f:
    f.write("0.0\n")
path = os.path.join(work, "mild.yaml")
rect_dir = os.path.join(work, "rectified")
out = subprocess.run([exe, "rectify", "--settings", path, "--sequence", seq, "--out", rect_dir], capture_output=True, text=True)
if out.returncode != 0:
    check("rectify", False, out.stderr.strip())
else:
    R1, R2, P1, P2, Q, _, _ = cv2.stereoRectify(K1, D1.reshape(1, -1), K2, D2.reshape(1, -1), size, R, T.reshape(3, 1), flags=cv2.CALIB_ZERO_DISPARITY, alpha=-1)
    for side, (K, D, Rk, Pk) in [("left", (K1, D1, R1, P1)), ("right", (K2, D2, R2, P2))]:
        mx, my = cv2.initUndistortRectifyMap(K, D.reshape(1, -1), Rk, Pk, size, cv2.CV_32FC1)
        raw = cv2.imread(os.path.join(seq, side, "1.png"))
        theirs = cv2.remap(raw, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0)
        ours = cv2.imread(os.path.join(rect_dir, side, "1.png"))
        inside = (mx >= 0) & (my >= 0) & (mx <= size[0] - 1) & (my <= size[1] - 1)
        diff = np.abs(ours.astype(int) - theirs.astype(int)).max(axis=2)[inside]
        check(f"rectify: {side} image", diff.max() <= 1, f"max {diff.max()} grey levels, {np.mean(diff > 0) * 100:.1f} % of pixels differ")
    settings = open(os.path.join(rect_dir, "settings.yaml")).read()
    check("rectify: settings.yaml", f"Camera.bf: " in settings and abs(float(settings.split("Camera.bf:")[1].split()[0]) + P2[0, 3]) < 1e-6,
          "bf = −P2[0,3]")

if failures:
    print(f"{len(failures)} checks failed: {', '.join(failures)}")
    sys.exit(1)
print("rectification agrees with OpenCV")
