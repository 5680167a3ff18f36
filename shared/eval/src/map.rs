//! Map accuracy, the paper's metric: the distance from each map point to the closest point on the ground-truth
//! mesh; points farther than a threshold (5 mm in the paper) are outliers, counted and excluded; mean and median
//! of the rest. Plus coverage: the share of the mesh's area that has a map point nearby.

use std::collections::HashMap;

use bdis_core::formats::ply::PointCloud;
use nalgebra::{Point3, Vector3};
use serde::{Deserialize, Serialize};

use crate::Stats;

#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum MapError {
    #[error("the mesh has no triangles")]
    NoTriangles,
    #[error("the map has no points")]
    NoPoints,
}

/// A triangle mesh.
#[derive(Debug, Clone, Default)]
pub struct Mesh {
    pub vertices: Vec<Point3<f64>>,
    pub triangles: Vec<[u32; 3]>,
}

impl Mesh {
    pub fn from_cloud(cloud: &PointCloud) -> Result<Self, MapError> {
        if cloud.faces.is_empty() {
            return Err(MapError::NoTriangles);
        }
        Ok(Self {
            vertices: cloud
                .positions
                .iter()
                .map(|p| Point3::new(f64::from(p[0]), f64::from(p[1]), f64::from(p[2])))
                .collect(),
            triangles: cloud.faces.clone(),
        })
    }

    fn corners(&self, t: usize) -> [Point3<f64>; 3] {
        self.triangles[t].map(|i| self.vertices[i as usize])
    }

    pub fn area(&self, t: usize) -> f64 {
        let [a, b, c] = self.corners(t);
        0.5 * (b - a).cross(&(c - a)).norm()
    }
}

/// Closest point to `p` on triangle (a, b, c): the Voronoi-region method (Ericson, Real-Time Collision
/// Detection, §5.1.5).
pub fn closest_point_on_triangle(p: &Point3<f64>, a: &Point3<f64>, b: &Point3<f64>, c: &Point3<f64>) -> Point3<f64> {
    let (ab, ac, ap) = (b - a, c - a, p - a);
    let (d1, d2) = (ab.dot(&ap), ac.dot(&ap));
    if d1 <= 0.0 && d2 <= 0.0 {
        return *a;
    }
    let bp = p - b;
    let (d3, d4) = (ab.dot(&bp), ac.dot(&bp));
    if d3 >= 0.0 && d4 <= d3 {
        return *b;
    }
    let vc = d1 * d4 - d3 * d2;
    if vc <= 0.0 && d1 >= 0.0 && d3 <= 0.0 {
        return a + ab * (d1 / (d1 - d3));
    }
    let cp = p - c;
    let (d5, d6) = (ab.dot(&cp), ac.dot(&cp));
    if d6 >= 0.0 && d5 <= d6 {
        return *c;
    }
    let vb = d5 * d2 - d1 * d6;
    if vb <= 0.0 && d2 >= 0.0 && d6 <= 0.0 {
        return a + ac * (d2 / (d2 - d6));
    }
    let va = d3 * d6 - d5 * d4;
    if va <= 0.0 && (d4 - d3) >= 0.0 && (d5 - d6) >= 0.0 {
        return b + (c - b) * ((d4 - d3) / ((d4 - d3) + (d5 - d6)));
    }
    let denom = 1.0 / (va + vb + vc);
    a + ab * (vb * denom) + ac * (vc * denom)
}

#[derive(Debug, Clone)]
struct Node {
    min: Vector3<f64>,
    max: Vector3<f64>,
    /// Leaf: `start..start + count` into the triangle order; inner: children at `start` and `start + 1`.
    start: usize,
    count: usize,
}

/// A bounding-volume hierarchy over a mesh's triangles for nearest-point queries.
#[derive(Debug, Clone)]
pub struct MeshIndex {
    mesh: Mesh,
    order: Vec<usize>,
    nodes: Vec<Node>,
}

fn bounds(mesh: &Mesh, tris: &[usize]) -> (Vector3<f64>, Vector3<f64>) {
    let mut min = Vector3::repeat(f64::INFINITY);
    let mut max = Vector3::repeat(f64::NEG_INFINITY);
    for &t in tris {
        for v in mesh.corners(t) {
            min = min.inf(&v.coords);
            max = max.sup(&v.coords);
        }
    }
    (min, max)
}

impl MeshIndex {
    pub fn new(mesh: Mesh) -> Result<Self, MapError> {
        if mesh.triangles.is_empty() {
            return Err(MapError::NoTriangles);
        }
        let mut order: Vec<usize> = (0..mesh.triangles.len()).collect();
        let centroid = |t: usize| {
            let [a, b, c] = mesh.corners(t);
            (a.coords + b.coords + c.coords) / 3.0
        };
        let (min, max) = bounds(&mesh, &order);
        let mut nodes = vec![Node { min, max, start: 0, count: order.len() }];
        // Build breadth-first with an explicit work list: (node index, range start, range end).
        let mut work = vec![(0usize, 0usize, order.len())];
        while let Some((n, lo, hi)) = work.pop() {
            if hi - lo <= 4 {
                nodes[n].start = lo;
                nodes[n].count = hi - lo;
                continue;
            }
            let extent = nodes[n].max - nodes[n].min;
            let axis = extent.imax();
            let mid = (lo + hi) / 2;
            order[lo..hi].select_nth_unstable_by(mid - lo, |&a, &b| centroid(a)[axis].total_cmp(&centroid(b)[axis]));
            let child = nodes.len();
            for (s, e) in [(lo, mid), (mid, hi)] {
                let (mn, mx) = bounds(&mesh, &order[s..e]);
                nodes.push(Node { min: mn, max: mx, start: 0, count: 0 });
            }
            nodes[n].start = child;
            nodes[n].count = 0;
            work.push((child, lo, mid));
            work.push((child + 1, mid, hi));
        }
        Ok(Self { mesh, order, nodes })
    }

    pub fn mesh(&self) -> &Mesh {
        &self.mesh
    }

    /// Distance from `p` to the mesh.
    pub fn distance(&self, p: &Point3<f64>) -> f64 {
        let (foot, _) = self.closest(p);
        (foot - p).norm()
    }

    /// The closest point to `p` on the mesh and the unit normal of its triangle (as the triangle's corners wind).
    pub fn closest(&self, p: &Point3<f64>) -> (Point3<f64>, Vector3<f64>) {
        let box_dist2 = |n: &Node| {
            let d = (n.min - p.coords).sup(&(p.coords - n.max)).sup(&Vector3::zeros());
            d.norm_squared()
        };
        let mut best = f64::INFINITY;
        let mut best_at = (*p, Vector3::z());
        let mut stack = vec![0usize];
        while let Some(n) = stack.pop() {
            let node = &self.nodes[n];
            if box_dist2(node) >= best {
                continue;
            }
            if node.count > 0 {
                for &t in &self.order[node.start..node.start + node.count] {
                    let [a, b, c] = self.mesh.corners(t);
                    let foot = closest_point_on_triangle(p, &a, &b, &c);
                    let d2 = (foot - p).norm_squared();
                    if d2 < best {
                        best = d2;
                        let normal = (b - a).cross(&(c - a)).try_normalize(1e-300).unwrap_or(Vector3::z());
                        best_at = (foot, normal);
                    }
                }
            } else {
                // Nearer child last, so it is searched first.
                let (l, r) = (node.start, node.start + 1);
                if box_dist2(&self.nodes[l]) < box_dist2(&self.nodes[r]) {
                    stack.extend([r, l]);
                } else {
                    stack.extend([l, r]);
                }
            }
        }
        best_at
    }
}

/// Where a second layer counts: from `thickness` (the map's own when `None`, see [`second_layer_fraction`]) to
/// `max_gap`, in the map's unit.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Layers {
    pub max_gap: f64,
    pub thickness: Option<f64>,
}

/// The map-to-mesh figures.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct MapScore {
    pub points: usize,
    pub outlier_threshold: f64,
    pub outliers: usize,
    pub outlier_fraction: f64,
    /// Distances of the inliers.
    pub inliers: Stats,
    /// Share of the mesh area (by triangle) with a map point within `coverage_radius` of the triangle's centroid.
    pub coverage: f64,
    pub coverage_radius: f64,
    /// Share of the inliers with a second layer: see [`second_layer_fraction`].
    #[serde(default)]
    pub second_layer: f64,
    #[serde(default)]
    pub second_layer_gap: f64,
    /// The least gap that counted as a second layer: the map's own thickness, or the one asked for.
    #[serde(default)]
    pub second_layer_thickness: f64,
    /// Share of all points farther than `outlier_threshold` from the mesh on the cameras' side of it: floating
    /// in front of the tissue, where instruments are (see [`in_front_fraction`]); `None` without cameras.
    #[serde(default)]
    pub in_front: Option<f64>,
}

/// The share of `points` farther than `threshold` from the mesh and in front of it: on the side of the nearest
/// of `cameras` (positions in the mesh's frame). Instruments, smoke and matches smeared across a silhouette
/// float there; a wrong match behind the surface does not count.
pub fn in_front_fraction(points: &[Point3<f64>], index: &MeshIndex, cameras: &[Point3<f64>], threshold: f64) -> f64 {
    if points.is_empty() || cameras.is_empty() {
        return 0.0;
    }
    let in_front = points
        .iter()
        .filter(|p| {
            let (foot, _) = index.closest(p);
            if (*p - foot).norm() <= threshold {
                return false;
            }
            let camera = cameras
                .iter()
                .min_by(|a, b| (*a - *p).norm_squared().total_cmp(&(*b - *p).norm_squared()))
                .unwrap_or(&foot);
            (*p - foot).dot(&(camera - foot)) > 0.0
        })
        .count();
    in_front as f64 / points.len() as f64
}

/// Where two passes over the same tissue left two surfaces instead of one: the share of inlier points (within
/// `outlier_threshold` of the mesh) that have a second layer — among the points whose feet on the mesh are
/// within `radius` of theirs, at least a quarter (and 2) lie more than the map's own thickness and at most
/// `max_gap` in front of or behind them, along the mesh's normal. The thickness is 3 robust σ of the inliers'
/// signed distances (1.4826 · MAD), so noise is not a layer; `radius` is twice the median spacing of the feet
/// (a neighbourhood of a few points whatever the map's density). Both come from the map, in its unit. A given
/// `thickness` replaces the map's own: two maps of different noise are then compared with one yardstick (a
/// sharper map's own thickness is thinner, so more of its tail would count). Returns the share and the thickness
/// used.
pub fn second_layer_fraction(
    points: &[Point3<f64>],
    index: &MeshIndex,
    outlier_threshold: f64,
    max_gap: f64,
    thickness: Option<f64>,
) -> (f64, f64) {
    // Foot on the mesh and signed offset along its normal, per inlier.
    let mut feet: Vec<(Point3<f64>, f64)> = Vec::with_capacity(points.len());
    for p in points {
        let (foot, normal) = index.closest(p);
        let offset = (p - foot).dot(&normal);
        if offset.abs() <= outlier_threshold {
            feet.push((foot, offset));
        }
    }
    if feet.len() < 3 {
        return (0.0, thickness.unwrap_or(0.0));
    }
    let median = |v: &mut Vec<f64>| {
        v.sort_by(f64::total_cmp);
        v[v.len() / 2]
    };
    let thickness = thickness.unwrap_or_else(|| {
        let mut offsets: Vec<f64> = feet.iter().map(|f| f.1).collect();
        let centre = median(&mut offsets);
        let mut deviations: Vec<f64> = offsets.iter().map(|o| (o - centre).abs()).collect();
        3.0 * 1.4826 * median(&mut deviations)
    });
    // Spacing: the median distance from a foot to its nearest other foot, by a hash grid (cell = a first guess
    // from the bounding box and the count, refined once).
    let grid_of = |cell: f64| {
        let mut grid: HashMap<(i64, i64, i64), Vec<u32>> = HashMap::new();
        for (i, (f, _)) in feet.iter().enumerate() {
            grid.entry(key(&f.coords, cell)).or_default().push(i as u32);
        }
        grid
    };
    let (lo, hi) =
        feet.iter().fold((Vector3::repeat(f64::INFINITY), Vector3::repeat(f64::NEG_INFINITY)), |(lo, hi), (f, _)| {
            (lo.inf(&f.coords), hi.sup(&f.coords))
        });
    let extent = hi - lo;
    // Feet lie on a surface: area ≈ the two largest extents' product.
    let mut e = [extent.x, extent.y, extent.z];
    e.sort_by(f64::total_cmp);
    let guess = (e[1] * e[2] / feet.len() as f64).sqrt().max(1e-12);
    let grid = grid_of(guess);
    let mut nearest: Vec<f64> = feet
        .iter()
        .enumerate()
        .map(|(i, (f, _))| {
            neighbours(&grid, f, guess, 1)
                .filter(|&j| j != i)
                .map(|j| (feet[j].0 - f).norm())
                .fold(f64::INFINITY, f64::min)
        })
        .filter(|d| d.is_finite())
        .collect();
    if nearest.is_empty() {
        return (0.0, thickness);
    }
    let radius = 2.0 * median(&mut nearest);
    let grid = grid_of(radius);
    let mut layered = 0usize;
    for (i, (f, offset)) in feet.iter().enumerate() {
        let (mut near, mut apart) = (0usize, 0usize);
        for j in neighbours(&grid, f, radius, 1) {
            if j == i || (feet[j].0 - f).norm() > radius {
                continue;
            }
            near += 1;
            let gap = (feet[j].1 - offset).abs();
            if gap > thickness && gap <= max_gap {
                apart += 1;
            }
        }
        if apart >= 2 && 4 * apart >= near {
            layered += 1;
        }
    }
    (layered as f64 / feet.len() as f64, thickness)
}

fn key(v: &Vector3<f64>, cell: f64) -> (i64, i64, i64) {
    ((v.x / cell).floor() as i64, (v.y / cell).floor() as i64, (v.z / cell).floor() as i64)
}

/// Indices of the feet in the cells within `reach` cells of `f`'s.
fn neighbours<'a>(
    grid: &'a HashMap<(i64, i64, i64), Vec<u32>>,
    f: &Point3<f64>,
    cell: f64,
    reach: i64,
) -> impl Iterator<Item = usize> + 'a {
    let (cx, cy, cz) = key(&f.coords, cell);
    (-reach..=reach).flat_map(move |dx| {
        (-reach..=reach).flat_map(move |dy| {
            (-reach..=reach)
                .flat_map(move |dz| grid.get(&(cx + dx, cy + dy, cz + dz)).into_iter().flatten().map(|&j| j as usize))
        })
    })
}

/// Scores map `points` against the mesh; `layers`: where a second layer counts ([`second_layer_fraction`]).
pub fn score_map(
    points: &[Point3<f64>],
    index: &MeshIndex,
    outlier_threshold: f64,
    coverage_radius: f64,
    layers: Layers,
) -> Result<MapScore, MapError> {
    if points.is_empty() {
        return Err(MapError::NoPoints);
    }
    let mut inliers = Vec::with_capacity(points.len());
    let mut outliers = 0;
    for p in points {
        let d = index.distance(p);
        if d > outlier_threshold {
            outliers += 1;
        } else {
            inliers.push(d);
        }
    }
    // Coverage: a hash grid of the map points with the radius as cell size.
    let cell = |v: &Vector3<f64>| {
        (
            (v.x / coverage_radius).floor() as i64,
            (v.y / coverage_radius).floor() as i64,
            (v.z / coverage_radius).floor() as i64,
        )
    };
    let mut grid: HashMap<(i64, i64, i64), Vec<u32>> = HashMap::new();
    for (i, p) in points.iter().enumerate() {
        grid.entry(cell(&p.coords)).or_default().push(i as u32);
    }
    let mesh = index.mesh();
    let (mut covered, mut total) = (0.0, 0.0);
    for t in 0..mesh.triangles.len() {
        let [a, b, c] = mesh.corners(t);
        let centroid = (a.coords + b.coords + c.coords) / 3.0;
        let area = mesh.area(t);
        total += area;
        let (cx, cy, cz) = cell(&centroid);
        let near = (-1..=1).any(|dx| {
            (-1..=1).any(|dy| {
                (-1..=1).any(|dz| {
                    grid.get(&(cx + dx, cy + dy, cz + dz)).is_some_and(|ids| {
                        ids.iter().any(|&i| (points[i as usize].coords - centroid).norm() <= coverage_radius)
                    })
                })
            })
        });
        if near {
            covered += area;
        }
    }
    let (second_layer, second_layer_thickness) =
        second_layer_fraction(points, index, outlier_threshold, layers.max_gap, layers.thickness);
    Ok(MapScore {
        points: points.len(),
        outlier_threshold,
        outliers,
        outlier_fraction: outliers as f64 / points.len() as f64,
        inliers: Stats::of(&mut inliers),
        coverage: if total > 0.0 { covered / total } else { 0.0 },
        coverage_radius,
        second_layer,
        second_layer_gap: layers.max_gap,
        second_layer_thickness,
        in_front: None,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A 100 × 100 mm plane z = 0 split into 2·n² triangles.
    fn plane(n: usize) -> Mesh {
        let step = 100.0 / n as f64;
        let mut m = Mesh::default();
        for j in 0..=n {
            for i in 0..=n {
                m.vertices.push(Point3::new(i as f64 * step, j as f64 * step, 0.0));
            }
        }
        let id = |i: usize, j: usize| (j * (n + 1) + i) as u32;
        for j in 0..n {
            for i in 0..n {
                m.triangles.push([id(i, j), id(i + 1, j), id(i + 1, j + 1)]);
                m.triangles.push([id(i, j), id(i + 1, j + 1), id(i, j + 1)]);
            }
        }
        m
    }

    #[test]
    fn closest_points_in_every_voronoi_region() {
        let (a, b, c) = (Point3::new(0.0, 0.0, 0.0), Point3::new(1.0, 0.0, 0.0), Point3::new(0.0, 1.0, 0.0));
        let q = |x: f64, y: f64, z: f64| closest_point_on_triangle(&Point3::new(x, y, z), &a, &b, &c);
        assert!((q(0.2, 0.2, 5.0) - Point3::new(0.2, 0.2, 0.0)).norm() < 1e-12); // face
        assert_eq!(q(-1.0, -1.0, 0.0), a); // vertex
        assert_eq!(q(2.0, -0.5, 0.0), b);
        assert_eq!(q(0.5, -1.0, 1.0), Point3::new(0.5, 0.0, 0.0)); // edge ab
        assert!((q(1.0, 1.0, 0.0) - Point3::new(0.5, 0.5, 0.0)).norm() < 1e-12); // edge bc
    }

    #[test]
    fn bvh_distance_matches_brute_force() {
        let mut mesh = plane(12);
        // Crumple it so the hierarchy is not trivially flat.
        for v in &mut mesh.vertices {
            v.z = 3.0 * (v.x * 0.1).sin() * (v.y * 0.07).cos();
        }
        let index = MeshIndex::new(mesh.clone()).unwrap();
        for k in 0..300 {
            let p = Point3::new((k * 37 % 140) as f64 - 20.0, (k * 53 % 130) as f64 - 15.0, (k % 17) as f64 - 8.0);
            let brute = (0..mesh.triangles.len())
                .map(|t| {
                    let [a, b, c] = mesh.corners(t);
                    (closest_point_on_triangle(&p, &a, &b, &c) - p).norm()
                })
                .fold(f64::INFINITY, f64::min);
            assert!((index.distance(&p) - brute).abs() < 1e-12, "{p:?}");
        }
    }

    #[test]
    fn a_map_sampled_from_the_mesh_with_known_noise_and_outliers() {
        let index = MeshIndex::new(plane(20)).unwrap();
        // 10 000 points on the plane, offset along the normal by ±σ (half each): every inlier distance is σ;
        // every 20th point is lifted 10 mm: an outlier beyond the 5 mm threshold.
        let sigma = 0.3;
        let points: Vec<Point3<f64>> = (0..10_000)
            .map(|i| {
                let (x, y) = ((i % 100) as f64 + 0.5, (i / 100) as f64 + 0.5);
                let z = if i % 20 == 0 {
                    10.0
                } else if i % 2 == 0 {
                    sigma
                } else {
                    -sigma
                };
                Point3::new(x, y, z)
            })
            .collect();
        let s = score_map(&points, &index, 5.0, 2.0, Layers { max_gap: 2.0, thickness: None }).unwrap();
        assert_eq!(s.outliers, 500);
        assert!((s.outlier_fraction - 0.05).abs() < 1e-12);
        assert!((s.inliers.mean - sigma).abs() < 1e-9 && (s.inliers.median - sigma).abs() < 1e-9);
        assert!(s.coverage > 0.99, "the points cover the whole plane: {}", s.coverage);
        // Half the plane covered → half the coverage.
        let half: Vec<Point3<f64>> = points.iter().copied().filter(|p| p.x < 50.0).collect();
        let s = score_map(&half, &index, 5.0, 2.0, Layers { max_gap: 2.0, thickness: None }).unwrap();
        assert!((s.coverage - 0.5).abs() < 0.05, "{}", s.coverage);
    }

    /// A noisy single surface has no second layer; a strip seen twice, 1 mm apart, has one there (both of its
    /// layers' points count); a copy 3 mm away is beyond the 2 mm asked about.
    #[test]
    fn a_second_pass_one_millimetre_off_is_a_second_layer() {
        let index = MeshIndex::new(plane(20)).unwrap();
        let noise = |i: usize| ((i * 7919 % 1000) as f64 / 1000.0 - 0.5) * 0.2;
        let surface: Vec<Point3<f64>> = (0..40_000)
            .map(|i| Point3::new((i % 200) as f64 * 0.5 + 0.25, (i / 200) as f64 * 0.5 + 0.25, noise(i)))
            .collect();
        let single = second_layer_fraction(&surface, &index, 5.0, 2.0, None).0;
        assert!(single < 0.01, "one noisy surface: {single}");
        // The strip x < 20 mm seen again 1 mm above (a fifth of the plane).
        let again = |lift: f64| {
            let mut p = surface.clone();
            p.extend(surface.iter().filter(|q| q.x < 20.0).map(|q| Point3::new(q.x + 0.1, q.y + 0.1, q.z + lift)));
            p
        };
        let twice = again(1.0);
        let expected = 2.0 * 8_000.0 / twice.len() as f64;
        let layered = second_layer_fraction(&twice, &index, 5.0, 2.0, None).0;
        assert!((layered - expected).abs() < 0.03, "{layered} against {expected}");
        let far = second_layer_fraction(&again(3.0), &index, 5.0, 2.0, None).0;
        assert!(far < 0.01, "a copy 3 mm away is no second layer within 2 mm: {far}");
    }
}
