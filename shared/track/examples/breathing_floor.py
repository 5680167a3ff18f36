"""What a rigid tracker could do under breathing, against what ours did (a development tool, issue #22).

    python3 breathing_floor.py <render> <run>/trajectory.tum [SIGMA_PX] [POINTS]

<render> is an abdomen render with `synth --breathing` (its gt/mesh.ply is the mean wall, a regular grid of the
height field; its gt/depth is each frame's breathing tissue). For every 10th frame, two figures:

- the deformation's rigid part: the best rigid motion (Umeyama) taking the mean wall's points to the breathing
  tissue's in view (same material point = same world x, y on a height field), and where it would put the camera
  if the tissue were taken as still;
- an ideal rigid stereo tracker: the camera pose minimising the (u, v, u_R) reprojection error of the MEAN wall's
  points onto where the breathing tissue shows them — exact correspondences, POINTS random pixels (400), σ
  SIGMA_PX (0.35, the tracker's aligned measurements), Huber at 2.45σ, and ORB-SLAM2's rounds of outlier
  rejection (χ² > 7.815), started 1 mm off along the weak direction (sideways, turned to keep the view).

Both are compared with the run's trajectory, SE(3)-aligned to the truth as the ATE is. Numpy only; a few seconds.

    python3 breathing_floor.py <render> <out.tum> --features <map.txt> [--colon]

with `track_sequence <render> <out.tum> 12 --dump-map <map.txt>` (beside this): the same ideal tracker over the
points the tracker itself had (the first keyframe's, whose true positions are on the mean wall: t = 0 is the rest
phase), frame by frame against the tracker's own error relative to its first frame. `--colon` for a colon render
(the default breathing: an oval, cos 2θ · cos(2πz/40 mm), about the tube's centreline; seed 2026's shape).
"""
import sys
import numpy as np

seq, est_path = sys.argv[1], sys.argv[2]
features = sys.argv[sys.argv.index('--features') + 1] if '--features' in sys.argv else None
colon = '--colon' in sys.argv
numbers = [a for a in sys.argv[3:] if a not in ('--features', '--colon') and a != features]
sigma = float(numbers[0]) if numbers else 0.35
n_points = int(numbers[1]) if len(numbers) > 1 else 400


def load_tum(path):
    rows = [l.split() for l in open(path) if l.strip() and not l.startswith('#')]
    return np.array([[float(x) for x in r] for r in rows])


def rot(q):
    x, y, z, w = q
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                     [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                     [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])


def rodrigues(w):
    th = np.linalg.norm(w)
    if th < 1e-12:
        return np.eye(3)
    k = w / th
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + np.sin(th) * K + (1 - np.cos(th)) * K @ K


def umeyama(src, dst):
    ms, md = src.mean(0), dst.mean(0)
    U, _, Vt = np.linalg.svd((src - ms).T @ (dst - md))
    D = np.eye(3)
    D[2, 2] = np.sign(np.linalg.det(Vt.T @ U.T))
    R = Vt.T @ D @ U.T
    return R, md - R @ ms


def pfm(path):
    with open(path, 'rb') as f:
        f.readline()
        w, h = map(int, f.readline().split())
        scale = float(f.readline())
        a = np.frombuffer(f.read(), dtype='<f4' if scale < 0 else '>f4').reshape(h, w)
    return a[::-1]


def mesh_grid(path):
    data = open(path, 'rb').read()
    end = data.index(b'end_header\n') + len(b'end_header\n')
    n = int([l for l in data[:end].decode().split('\n') if l.startswith('element vertex')][0].split()[2])
    v = np.frombuffer(data[end:end + 12 * n], dtype='<f4').reshape(n, 3).astype(float)
    side = int(round(np.sqrt(n)))
    return v[0, 0], v[1, 0] - v[0, 0], v[:, 2].reshape(side, side)


settings = {l.split(':')[0]: l.split(':')[1] for l in open(seq + '/settings.yaml') if l.startswith('Camera.')}
fx, fy, cx, cy, bf = (float(settings['Camera.' + k]) for k in ('fx', 'fy', 'cx', 'cy', 'bf'))
x0, step, Z = (None, None, None) if colon else mesh_grid(seq + '/gt/mesh.ply')


def mean_wall_z(x, y):
    fi, fj = (x - x0) / step, (y - x0) / step
    i, j = np.floor(fi).astype(int), np.floor(fj).astype(int)
    a, b = fi - i, fj - j
    return Z[j, i] * (1 - a) * (1 - b) + Z[j, i + 1] * a * (1 - b) + Z[j + 1, i] * (1 - a) * b + Z[j + 1, i + 1] * a * b


def ideal_camera(P, obs, R_w, c_w):
    """The camera centre that best explains observations `obs` (u, v, u_R) of world points `P`, started 1 mm off
    the truth (R_w, c_w) along the weak direction."""
    turn = rodrigues(np.array([0.0, 1.0 / 55.0, 0.0]))
    Rc = turn @ R_w.T
    tc = -Rc @ (c_w + R_w @ np.array([1.0, 0.0, 0.0]))

    def residual(Rc, tc):
        pc = (Rc @ P.T).T + tc
        iz = 1 / pc[:, 2]
        uu = fx * pc[:, 0] * iz + cx
        return (np.stack([uu, fy * pc[:, 1] * iz + cy, uu - bf * iz], 1) - obs).ravel()

    outlier = np.zeros(len(P), bool)
    for it in range(40):
        r0 = residual(Rc, tc)
        J = np.zeros((len(r0), 6))
        for k in range(6):
            d = np.zeros(6)
            d[k] = 1e-6
            J[:, k] = (residual(rodrigues(d[:3]) @ Rc, rodrigues(d[:3]) @ tc + d[3:]) - r0) / 1e-6
        a = np.abs(r0) / sigma
        w = np.where(a < 2.45, 1.0, 2.45 / np.maximum(a, 1e-12)) * np.repeat(~outlier, 3)
        dx = np.linalg.solve(J.T @ (J * w[:, None]), -J.T @ (w * r0))
        Rc, tc = rodrigues(dx[:3]) @ Rc, rodrigues(dx[:3]) @ tc + dx[3:]
        if it % 10 == 9:
            outlier = ((r0 / sigma) ** 2).reshape(-1, 3).sum(1) > 7.815
    return -Rc.T @ tc


def project(R_w, c_w, Q):
    pc = (R_w.T @ (Q - c_w).T).T
    u = fx * pc[:, 0] / pc[:, 2] + cx
    return np.stack([u, fy * pc[:, 1] / pc[:, 2] + cy, u - bf / pc[:, 2]], 1)


gt, est = load_tum(seq + '/gt/poses.tum'), load_tum(est_path)
if features:
    # The first keyframe's observed pixels; their material points on the mean wall, seen at t = 0 (rest).
    uv = np.array([[float(x) for x in l.split()[4:6]] for l in open(features) if l.startswith('O ') and l.split()[2] == '0'])
    d0 = pfm(seq + '/gt/depth/1.pfm')
    x, y = np.floor(uv[:, 0]).astype(int), np.floor(uv[:, 1]).astype(int)
    a, b = uv[:, 0] - x, uv[:, 1] - y
    z = d0[y, x] * (1 - a) * (1 - b) + d0[y, x + 1] * a * (1 - b) + d0[y + 1, x] * (1 - a) * b + d0[y + 1, x + 1] * a * b
    R0, c0 = rot(gt[0, 4:8]), gt[0, 1:4]
    P = (R0 @ np.stack([(uv[:, 0] - cx) * z / fx, (uv[:, 1] - cy) * z / fy, z])).T + c0
    P = P[np.isfinite(P).all(1)]
    E0 = np.linalg.inv(np.block([[rot(est[0, 4:8]), est[0, 1:4, None]], [np.zeros((1, 3)), np.ones((1, 1))]]))
    print(f'{len(P)} points of the first keyframe; camera position error (mm): ideal rigid tracker / this run')
    for f in range(1, len(est)):
        depth = pfm(f'{seq}/gt/depth/{f + 1}.pfm')
        R_w, c_w = rot(gt[f, 4:8]), gt[f, 1:4]
        if colon:
            # The colon's breathing is analytic: radial, about the centreline at the point's height.
            centre_x, centre_y = 6 * np.sin(P[:, 2] / 40), 4 * np.sin(P[:, 2] / 55 + 1)
            th = np.arctan2(P[:, 1] - centre_y, P[:, 0] - centre_x)
            inward = 2 * np.sin(2 * np.pi * gt[f, 0] / 4) * np.cos(2 * th) * np.cos(2 * np.pi * P[:, 2] / 40)
            Q = P - inward[:, None] * np.stack([np.cos(th), np.sin(th), 0 * th], 1)
            ideal = np.linalg.norm(ideal_camera(P, project(R_w, c_w, Q), R_w, c_w) - c_w)
            G0 = np.block([[rot(gt[0, 4:8]).T, -rot(gt[0, 4:8]).T @ gt[0, 1:4, None]], [np.zeros((1, 3)), np.ones((1, 1))]])
            mine = (E0 @ np.r_[est[f, 1:4], 1])[:3] - (G0 @ np.r_[c_w, 1])[:3]
            print(f'frame {f}: {ideal:.3f} / {np.linalg.norm(mine):.3f}')
            continue
        # Where each material point is now: on this frame's tissue above the same (x, y).
        pc = (R_w.T @ (P - c_w).T).T
        u, v = fx * pc[:, 0] / pc[:, 2] + cx, fy * pc[:, 1] / pc[:, 2] + cy
        Q = P.copy()
        for _ in range(3):  # the tissue moved along z: find its depth where the point now projects
            xi, yi = np.clip(np.round(u).astype(int), 0, depth.shape[1] - 1), np.clip(np.round(v).astype(int), 0, depth.shape[0] - 1)
            zz = depth[yi, xi].astype(float)
            seen = (R_w @ np.stack([(u - cx) * zz / fx, (v - cy) * zz / fy, zz])).T + c_w
            Q[:, 2] = P[:, 2] + (seen[:, 2] - mean_wall_z(seen[:, 0], seen[:, 1]))
            pc = (R_w.T @ (Q - c_w).T).T
            u, v = fx * pc[:, 0] / pc[:, 2] + cx, fy * pc[:, 1] / pc[:, 2] + cy
        ideal = np.linalg.norm(ideal_camera(P, project(R_w, c_w, Q), R_w, c_w) - c_w)
        G0 = np.block([[rot(gt[0, 4:8]).T, -rot(gt[0, 4:8]).T @ gt[0, 1:4, None]], [np.zeros((1, 3)), np.ones((1, 1))]])
        mine = (E0 @ np.r_[est[f, 1:4], 1])[:3] - (G0 @ np.r_[c_w, 1])[:3]
        print(f'frame {f}: {ideal:.3f} / {np.linalg.norm(mine):.3f}')
    sys.exit(0)
R_a, t_a = umeyama(est[:, 1:4], gt[:, 1:4])
tracker_error = (R_a @ est[:, 1:4].T).T + t_a - gt[:, 1:4]
rows = []
for f in range(0, len(gt), 10):
    depth = pfm(f'{seq}/gt/depth/{f + 1}.pfm')[::4, ::4]
    v, u = np.mgrid[0:depth.shape[0], 0:depth.shape[1]] * 4.0
    ok = np.isfinite(depth)
    z, u, v = depth[ok].astype(float), u[ok], v[ok]
    R_w, c_w = rot(gt[f, 4:8]), gt[f, 1:4]
    seen = (R_w @ np.stack([(u - cx) * z / fx, (v - cy) * z / fy, z])).T + c_w
    mean = seen.copy()
    mean[:, 2] = mean_wall_z(seen[:, 0], seen[:, 1])
    # The rigid part: the tissue moved as a whole by (R, t); taken as still, the camera seems at R⁻¹(c − t).
    R, t = umeyama(mean, seen)
    rigid = R.T @ (c_w - t) - c_w
    # The ideal rigid tracker.
    pick = np.random.default_rng(f).choice(len(mean), min(n_points, len(mean)), replace=False)
    P, obs = mean[pick], np.stack([u, v, u - bf / z], 1)[pick]
    rows.append(np.r_[rigid, ideal_camera(P, obs, R_w, c_w) - c_w, tracker_error[f]])
rows = np.array(rows)
rms = lambda a: np.sqrt((a ** 2).sum(1).mean())
print(f'{len(rows)} frames; position error rms (mm): rigid part {rms(rows[:, 0:3]):.3f}, '
      f'ideal rigid tracker {rms(rows[:, 3:6]):.3f}, this run {rms(rows[:, 6:9]):.3f}')
