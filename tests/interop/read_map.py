"""Independent reader of a bdis-slam map (map.ply) with numpy only, and an independent accuracy check.

Reads the binary PLY by its header (read_formats.read_ply), checks the properties a map must have (x y z float,
red green blue uchar, keyframe_id and confidence float), that every value is finite, confidences lie in [0, 1]
and keyframe ids are whole numbers; then measures, for an evenly spaced subsample of points, the distance to
the nearest vertex of the ground-truth mesh (an upper bound of the distance to the surface: the renderer's mesh
has 0.5 mm vertex spacing) after moving the map by a given 4×4 transform. Prints one JSON object.

usage: read_map.py MAP.ply MESH.ply [TRANSFORM_JSON]
"""
import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).parent))
from read_formats import read_ply  # noqa: E402

EXPECTED = [["float", "x"], ["float", "y"], ["float", "z"], ["uchar", "red"], ["uchar", "green"],
            ["uchar", "blue"], ["float", "keyframe_id"], ["float", "confidence"]]


def header_props(path):
    data = path.read_bytes()
    header = data[: data.index(b"end_header\n")].decode("ascii").splitlines()
    return [line.split()[1:] for line in header if line.startswith("property")]


def main(map_path, mesh_path, transform=None):
    map_path, mesh_path = Path(map_path), Path(mesh_path)
    props = header_props(map_path)
    assert props == EXPECTED, f"map.ply properties {props}"
    v = read_ply(map_path)["vertex"]
    xyz = np.stack([v["x"], v["y"], v["z"]], axis=1).astype(np.float64)
    assert np.isfinite(xyz).all(), "non-finite positions"
    conf = v["confidence"]
    assert ((conf >= 0) & (conf <= 1)).all(), "confidence outside [0, 1]"
    kf = v["keyframe_id"]
    assert (kf == np.round(kf)).all() and (kf >= 0).all(), "keyframe ids not whole numbers"
    if transform is not None:
        t = np.array(transform, dtype=np.float64).reshape(4, 4)
        xyz = xyz @ t[:3, :3].T + t[:3, 3]
    mesh = read_ply(mesh_path)["vertex"]
    verts = np.stack([mesh["x"], mesh["y"], mesh["z"]], axis=1).astype(np.float64)
    sample = xyz[:: max(1, len(xyz) // 1500)]
    nearest = np.empty(len(sample))
    v2 = (verts ** 2).sum(axis=1)
    for i in range(0, len(sample), 100):
        chunk = sample[i : i + 100]
        d2 = (chunk ** 2).sum(axis=1)[:, None] - 2.0 * chunk @ verts.T + v2[None, :]
        nearest[i : i + 100] = np.sqrt(np.maximum(d2.min(axis=1), 0.0))
    inliers = nearest[nearest <= 5.0]
    print(json.dumps({
        "points": int(len(xyz)),
        "keyframes": int(len(np.unique(kf))),
        "confidence_min": float(conf.min()),
        "sampled": int(len(sample)),
        "nearest_vertex_median_mm": float(np.median(inliers)) if len(inliers) else None,
        "outlier_fraction": float(1.0 - len(inliers) / len(sample)),
    }))


if __name__ == "__main__":
    main(sys.argv[1], sys.argv[2], json.loads(sys.argv[3]) if len(sys.argv) > 3 else None)
