"""Independent reader for the files bdis-slam writes, from the format specifications, with numpy only.

PFM: header `Pf`/`PF`, `W H`, scale (negative = little-endian), then float32 rows from bottom to top.
PLY: `format binary_little_endian 1.0`, vertex properties in header order, then faces as `list uchar int`.
TUM: `t tx ty tz qx qy qz qw` per line. KITTI: 12 values of [R|t] per line, row-major.
Compares with expected.json (written by the Rust test with serde_json) and exits non-zero on any difference.
"""
import json
import sys
from pathlib import Path

import numpy as np


def read_pfm(path):
    data = path.read_bytes()
    lines, pos = [], 0
    while len(lines) < 3:  # three header lines, each ended by one newline
        end = data.index(b"\n", pos)
        lines.append(data[pos:end].decode("ascii").strip())
        pos = end + 1
    channels = {"Pf": 1, "PF": 3}[lines[0]]
    width, height = map(int, lines[1].split())
    scale = float(lines[2])
    dtype = "<f4" if scale < 0 else ">f4"
    rows = np.frombuffer(data, dtype=dtype, offset=pos).reshape(height, width * channels)
    return np.flipud(rows).reshape(-1), width, height


PLY_TYPES = {"float": "<f4", "uchar": "u1", "int": "<i4", "double": "<f8", "uint": "<u4"}


def read_ply(path):
    data = path.read_bytes()
    end = data.index(b"end_header\n") + len(b"end_header\n")
    header = data[:end].decode("ascii").splitlines()
    assert header[0] == "ply" and header[1] == "format binary_little_endian 1.0", header[:2]
    elements, current = [], None
    for line in header[2:]:
        words = line.split()
        if words[0] == "element":
            current = {"name": words[1], "count": int(words[2]), "props": []}
            elements.append(current)
        elif words[0] == "property":
            current["props"].append(words[1:])
    pos, out = end, {}
    for el in elements:
        if el["name"] == "vertex":
            dtype = np.dtype([(p[1], PLY_TYPES[p[0]]) for p in el["props"]])
            out["vertex"] = np.frombuffer(data, dtype=dtype, count=el["count"], offset=pos)
            pos += dtype.itemsize * el["count"]
        elif el["name"] == "face":
            dtype = np.dtype([("n", "u1"), ("i", "<i4", (3,))])
            out["face"] = np.frombuffer(data, dtype=dtype, count=el["count"], offset=pos)
            assert (out["face"]["n"] == 3).all()
            pos += dtype.itemsize * el["count"]
    assert pos == len(data), f"{len(data) - pos} trailing bytes"
    return out


def bits(a):
    return np.asarray(a, dtype="<f4").view("<u4").tolist()


def main(folder):
    d = Path(folder)
    exp = json.loads((d / "expected.json").read_text())
    problems = []

    for name in ["disparity", "rgb"]:
        values, w, h = read_pfm(d / f"{name}.pfm")
        if (w, h) != (exp[name]["width"], exp[name]["height"]) or bits(values) != exp[name]["bits"]:
            problems.append(f"{name}.pfm differs")

    ply = read_ply(d / "map.ply")
    v = ply["vertex"]
    xyz = np.stack([v["x"], v["y"], v["z"]], axis=1).reshape(-1)
    if bits(xyz) != exp["ply"]["xyz_bits"]:
        problems.append("map.ply positions differ")
    if np.stack([v["red"], v["green"], v["blue"]], axis=1).reshape(-1).tolist() != exp["ply"]["rgb"]:
        problems.append("map.ply colours differ")
    if bits(v["confidence"]) != exp["ply"]["confidence_bits"]:
        problems.append("map.ply confidence differs")
    if ply["face"]["i"].tolist() != exp["ply"]["faces"]:
        problems.append("map.ply faces differ")

    tum = np.loadtxt(d / "traj.tum", comments="#", ndmin=2)
    if tum.tolist() != exp["tum"]:
        problems.append("traj.tum differs")
    kitti = np.loadtxt(d / "traj.kitti", ndmin=2)
    if not np.array_equal(kitti, np.array(exp["kitti"])):
        diff = np.abs(kitti - np.array(exp["kitti"])).max()
        if diff > 1e-15:
            problems.append(f"traj.kitti differs by {diff}")
    # Rotations must be orthonormal as written.
    for row in kitti:
        r = row.reshape(3, 4)[:, :3]
        if np.abs(r @ r.T - np.eye(3)).max() > 1e-12:
            problems.append("traj.kitti has a non-orthonormal rotation")
            break

    if problems:
        print("\n".join(problems))
        sys.exit(1)
    print("all formats agree")


if __name__ == "__main__":
    main(sys.argv[1])
