//! PLY point clouds and meshes. We write binary little-endian (`x y z` float, `red green blue` uchar, optional
//! float properties, optional triangle faces); we read binary little-endian and ASCII files with any scalar
//! property types, so meshes from other tools load too.

use std::io::Write;
use std::path::Path;

use super::{FormatError, invalid, io_error, write_atomically};

/// Points with optional colours, named per-point float properties (e.g. `confidence`), and triangles.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct PointCloud {
    pub positions: Vec<[f32; 3]>,
    /// Same length as `positions` when present.
    pub colors: Option<Vec<[u8; 3]>>,
    /// Extra per-point float properties, each the length of `positions`.
    pub scalars: Vec<(String, Vec<f32>)>,
    /// Triangles as vertex indices (polygons read from files are fanned into triangles).
    pub faces: Vec<[u32; 3]>,
}

impl PointCloud {
    pub fn len(&self) -> usize {
        self.positions.len()
    }

    pub fn is_empty(&self) -> bool {
        self.positions.is_empty()
    }

    fn check(&self, path: &Path) -> Result<(), FormatError> {
        let n = self.positions.len();
        if self.colors.as_ref().is_some_and(|c| c.len() != n) {
            return Err(invalid(path, None, "PLY: colours and positions differ in length"));
        }
        for (name, values) in &self.scalars {
            if values.len() != n {
                return Err(invalid(
                    path,
                    None,
                    format!("PLY: property `{name}` has {} values for {n} points", values.len()),
                ));
            }
            if name.is_empty() || !name.chars().all(|c| c.is_ascii_alphanumeric() || c == '_') {
                return Err(invalid(path, None, format!("PLY: property name `{name}` must be [A-Za-z0-9_]+")));
            }
        }
        if let Some(f) = self.faces.iter().find(|f| f.iter().any(|&i| i as usize >= n)) {
            return Err(invalid(path, None, format!("PLY: face {f:?} refers to a vertex beyond {n}")));
        }
        Ok(())
    }
}

/// Writes a binary little-endian PLY.
pub fn write(path: &Path, cloud: &PointCloud) -> Result<(), FormatError> {
    cloud.check(path)?;
    write_atomically(path, |w| {
        let mut header = String::from("ply\nformat binary_little_endian 1.0\ncomment written by bdis-slam\n");
        header += &format!("element vertex {}\nproperty float x\nproperty float y\nproperty float z\n", cloud.len());
        if cloud.colors.is_some() {
            header += "property uchar red\nproperty uchar green\nproperty uchar blue\n";
        }
        for (name, _) in &cloud.scalars {
            header += &format!("property float {name}\n");
        }
        if !cloud.faces.is_empty() {
            header += &format!("element face {}\nproperty list uchar int vertex_indices\n", cloud.faces.len());
        }
        header += "end_header\n";
        w.write_all(header.as_bytes())?;
        let mut record = Vec::with_capacity(15 + 4 * cloud.scalars.len());
        for (i, p) in cloud.positions.iter().enumerate() {
            record.clear();
            for v in p {
                record.extend_from_slice(&v.to_le_bytes());
            }
            if let Some(colors) = &cloud.colors {
                record.extend_from_slice(&colors[i]);
            }
            for (_, values) in &cloud.scalars {
                record.extend_from_slice(&values[i].to_le_bytes());
            }
            w.write_all(&record)?;
        }
        for f in &cloud.faces {
            record.clear();
            record.push(3);
            for &i in f {
                record.extend_from_slice(&(i as i32).to_le_bytes());
            }
            w.write_all(&record)?;
        }
        Ok(())
    })
}

#[derive(Debug, Clone, Copy, PartialEq)]
enum Scalar {
    I8,
    U8,
    I16,
    U16,
    I32,
    U32,
    F32,
    F64,
}

impl Scalar {
    fn parse(name: &str) -> Option<Self> {
        Some(match name {
            "char" | "int8" => Self::I8,
            "uchar" | "uint8" => Self::U8,
            "short" | "int16" => Self::I16,
            "ushort" | "uint16" => Self::U16,
            "int" | "int32" => Self::I32,
            "uint" | "uint32" => Self::U32,
            "float" | "float32" => Self::F32,
            "double" | "float64" => Self::F64,
            _ => return None,
        })
    }

    fn size(self) -> usize {
        match self {
            Self::I8 | Self::U8 => 1,
            Self::I16 | Self::U16 => 2,
            Self::I32 | Self::U32 | Self::F32 => 4,
            Self::F64 => 8,
        }
    }

    fn read_le(self, b: &[u8]) -> f64 {
        match self {
            Self::I8 => f64::from(b[0] as i8),
            Self::U8 => f64::from(b[0]),
            Self::I16 => f64::from(i16::from_le_bytes([b[0], b[1]])),
            Self::U16 => f64::from(u16::from_le_bytes([b[0], b[1]])),
            Self::I32 => f64::from(i32::from_le_bytes([b[0], b[1], b[2], b[3]])),
            Self::U32 => f64::from(u32::from_le_bytes([b[0], b[1], b[2], b[3]])),
            Self::F32 => f64::from(f32::from_le_bytes([b[0], b[1], b[2], b[3]])),
            Self::F64 => f64::from_le_bytes([b[0], b[1], b[2], b[3], b[4], b[5], b[6], b[7]]),
        }
    }
}

#[derive(Debug)]
struct Property {
    name: String,
    /// `Some(count type)` for a list property.
    list_count: Option<Scalar>,
    value: Scalar,
}

#[derive(Debug)]
struct Element {
    name: String,
    count: usize,
    properties: Vec<Property>,
}

/// Reads values of one element record, from binary or ASCII data, into `out` (lists flattened, length-prefixed).
trait RecordSource {
    fn scalar(&mut self, t: Scalar) -> Result<f64, String>;
}

struct Binary<'a> {
    bytes: &'a [u8],
    pos: usize,
}

impl RecordSource for Binary<'_> {
    fn scalar(&mut self, t: Scalar) -> Result<f64, String> {
        let end = self.pos + t.size();
        let b = self.bytes.get(self.pos..end).ok_or_else(|| format!("data ends early at byte {}", self.pos))?;
        self.pos = end;
        Ok(t.read_le(b))
    }
}

struct Ascii<'a> {
    tokens: std::str::SplitAsciiWhitespace<'a>,
}

impl RecordSource for Ascii<'_> {
    fn scalar(&mut self, _t: Scalar) -> Result<f64, String> {
        let tok = self.tokens.next().ok_or("data ends early")?;
        tok.parse().map_err(|_| format!("`{tok}` is not a number"))
    }
}

/// Reads a PLY file (binary little-endian or ASCII).
pub fn read(path: &Path) -> Result<PointCloud, FormatError> {
    let bytes = std::fs::read(path).map_err(io_error(path))?;
    parse(&bytes, path)
}

/// Parses PLY bytes; `path` only names the source in errors.
pub fn parse(bytes: &[u8], path: &Path) -> Result<PointCloud, FormatError> {
    const END: &[u8] = b"end_header";
    let end =
        bytes.windows(END.len()).position(|w| w == END).ok_or_else(|| invalid(path, None, "PLY: no end_header"))?;
    let header = std::str::from_utf8(&bytes[..end]).map_err(|_| invalid(path, None, "PLY: header is not text"))?;
    let mut data_start = end + END.len();
    if bytes.get(data_start) == Some(&b'\r') {
        data_start += 1;
    }
    if bytes.get(data_start) == Some(&b'\n') {
        data_start += 1;
    }

    let mut format = None;
    let mut elements: Vec<Element> = Vec::new();
    for (i, line) in header.lines().enumerate() {
        let line_no = Some(i + 1);
        let words: Vec<&str> = line.split_whitespace().collect();
        match words.as_slice() {
            [] | ["comment", ..] | ["obj_info", ..] => {}
            ["ply"] if i == 0 => {}
            _ if i == 0 => return Err(invalid(path, line_no, "not a PLY file (first line must be `ply`)")),
            ["format", _, "1.0"] if format.is_some() => {
                return Err(invalid(path, line_no, "PLY: a second format line"));
            }
            ["format", f, "1.0"] => format = Some(f.to_string()),
            ["element", name, _] if elements.iter().any(|e| e.name == *name) => {
                return Err(invalid(path, line_no, format!("PLY: element `{name}` declared twice")));
            }
            ["element", name, count] => elements.push(Element {
                name: name.to_string(),
                count: count
                    .parse()
                    .map_err(|_| invalid(path, line_no, format!("PLY: bad element count `{count}`")))?,
                properties: Vec::new(),
            }),
            ["property", "list", count_t, value_t, name] => {
                let (Some(c), Some(v)) = (Scalar::parse(count_t), Scalar::parse(value_t)) else {
                    return Err(invalid(path, line_no, format!("PLY: unknown list type in `{line}`")));
                };
                let element =
                    elements.last_mut().ok_or_else(|| invalid(path, line_no, "PLY: property before element"))?;
                element.properties.push(Property { name: name.to_string(), list_count: Some(c), value: v });
            }
            ["property", t, name] => {
                let v = Scalar::parse(t).ok_or_else(|| invalid(path, line_no, format!("PLY: unknown type `{t}`")))?;
                let element =
                    elements.last_mut().ok_or_else(|| invalid(path, line_no, "PLY: property before element"))?;
                element.properties.push(Property { name: name.to_string(), list_count: None, value: v });
            }
            _ => return Err(invalid(path, line_no, format!("PLY: unsupported header line `{line}`"))),
        }
    }
    let data = &bytes[data_start..];
    let mut binary = Binary { bytes: data, pos: 0 };
    let text;
    let mut ascii = match format.as_deref() {
        Some("binary_little_endian") => None,
        Some("ascii") => {
            text = std::str::from_utf8(data).map_err(|_| invalid(path, None, "PLY: ASCII body is not text"))?;
            Some(Ascii { tokens: text.split_ascii_whitespace() })
        }
        Some(other) => return Err(invalid(path, None, format!("PLY: format `{other}` is not supported"))),
        None => return Err(invalid(path, None, "PLY: no format line")),
    };

    // A header can claim any count: before anything is reserved or looped over, the claim is checked against
    // the body, in which every record takes at least one byte per property (ASCII: a digit; binary: its size).
    // Without this, `element vertex 1000000000000` in a 100-byte file asked for terabytes (found by fuzzing).
    let mut least_bytes: u64 = 0;
    for element in &elements {
        let per_record: u64 = element
            .properties
            .iter()
            .map(|p| if ascii.is_some() { 1 } else { p.list_count.unwrap_or(p.value).size() as u64 })
            .sum();
        if element.count > 0 && per_record == 0 {
            return Err(invalid(path, None, format!("PLY: element `{}` has no properties", element.name)));
        }
        least_bytes = least_bytes.saturating_add(per_record.saturating_mul(element.count as u64));
    }
    if least_bytes > data.len() as u64 {
        return Err(invalid(
            path,
            None,
            format!("PLY: the header claims at least {least_bytes} bytes of elements, the body has {}", data.len()),
        ));
    }
    let mut cloud = PointCloud::default();
    let mut record = Vec::new();
    for element in &elements {
        let index_of = |n: &str| element.properties.iter().position(|p| p.name == n && p.list_count.is_none());
        let is_vertex = element.name == "vertex";
        let xyz = [index_of("x"), index_of("y"), index_of("z")];
        let rgb = [index_of("red"), index_of("green"), index_of("blue")];
        if is_vertex {
            if xyz.iter().any(Option::is_none) {
                return Err(invalid(path, None, "PLY: vertex element without x, y, z"));
            }
            cloud.positions.reserve(element.count);
            if rgb.iter().all(Option::is_some) {
                cloud.colors = Some(Vec::with_capacity(element.count));
            }
            for (k, p) in element.properties.iter().enumerate() {
                if p.list_count.is_none() && !xyz.contains(&Some(k)) && !rgb.contains(&Some(k)) {
                    cloud.scalars.push((p.name.clone(), Vec::with_capacity(element.count)));
                }
            }
        }
        for n in 0..element.count {
            record.clear();
            let mut list: Vec<f64> = Vec::new();
            for p in &element.properties {
                let mut next = |t: Scalar| match ascii.as_mut() {
                    Some(a) => a.scalar(t),
                    None => binary.scalar(t),
                };
                let err = |e: String| invalid(path, None, format!("PLY: element `{}` #{n}: {e}", element.name));
                match p.list_count {
                    None => record.push(next(p.value).map_err(err)?),
                    Some(count_t) => {
                        let count = next(count_t).map_err(err)?;
                        record.push(f64::NAN); // placeholder keeps property indices aligned
                        list.clear();
                        for _ in 0..count as usize {
                            list.push(next(p.value).map_err(err)?);
                        }
                    }
                }
            }
            if is_vertex {
                let get = |i: Option<usize>| i.map_or(0.0, |i| record[i]);
                cloud.positions.push([get(xyz[0]) as f32, get(xyz[1]) as f32, get(xyz[2]) as f32]);
                if let Some(colors) = cloud.colors.as_mut() {
                    colors.push([get(rgb[0]) as u8, get(rgb[1]) as u8, get(rgb[2]) as u8]);
                }
                let mut s = 0;
                for (k, p) in element.properties.iter().enumerate() {
                    if p.list_count.is_none() && !xyz.contains(&Some(k)) && !rgb.contains(&Some(k)) {
                        cloud.scalars[s].1.push(record[k] as f32);
                        s += 1;
                    }
                }
            } else if element.name == "face" && list.len() >= 3 {
                for k in 1..list.len() - 1 {
                    cloud.faces.push([list[0] as u32, list[k] as u32, list[k + 1] as u32]);
                }
            }
        }
    }
    if ascii.is_none() && binary.pos != data.len() {
        return Err(invalid(
            path,
            None,
            format!("PLY: {} bytes of data after the last element", data.len() - binary.pos),
        ));
    }
    if let Some(f) = cloud.faces.iter().find(|f| f.iter().any(|&i| i as usize >= cloud.positions.len())) {
        return Err(invalid(path, None, format!("PLY: face {f:?} refers to a missing vertex")));
    }
    Ok(cloud)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sample() -> PointCloud {
        PointCloud {
            positions: vec![[1.0, -2.5, 3.25], [0.0, 0.5, -1.0e-3], [7.0, 8.0, 9.0]],
            colors: Some(vec![[255, 0, 7], [1, 2, 3], [9, 9, 9]]),
            scalars: vec![("confidence".into(), vec![0.5, 1.0, 0.0])],
            faces: vec![[0, 1, 2]],
        }
    }

    #[test]
    fn binary_layout_is_hand_checked_and_round_trips() {
        let dir = std::env::temp_dir().join(format!("bdis-ply-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("m.ply");
        let cloud = sample();
        write(&path, &cloud).unwrap();
        let bytes = std::fs::read(&path).unwrap();
        let header = "ply\nformat binary_little_endian 1.0\ncomment written by bdis-slam\nelement vertex 3\n\
property float x\nproperty float y\nproperty float z\nproperty uchar red\nproperty uchar green\nproperty uchar blue\n\
property float confidence\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n";
        assert_eq!(&bytes[..header.len()], header.as_bytes());
        let body = &bytes[header.len()..];
        assert_eq!(body.len(), 3 * (12 + 3 + 4) + 13);
        // First vertex: x = 1.0 LE, then y, z, then the colour bytes, then the confidence.
        assert_eq!(&body[0..4], &1.0f32.to_le_bytes());
        assert_eq!(&body[4..8], &(-2.5f32).to_le_bytes());
        assert_eq!(&body[12..15], &[255, 0, 7]);
        assert_eq!(&body[15..19], &0.5f32.to_le_bytes());
        assert_eq!(&body[57..], &[3, 0, 0, 0, 0, 1, 0, 0, 0, 2, 0, 0, 0]);
        assert_eq!(read(&path).unwrap(), cloud);
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn reads_ascii_meshes_with_quads_and_doubles() {
        let text = "ply\nformat ascii 1.0\nelement vertex 4\nproperty double x\nproperty double y\nproperty double z\n\
element face 1\nproperty list uchar uint vertex_index\nend_header\n0 0 0\n1 0 0\n1 1 0\n0 1 0\n4 0 1 2 3\n";
        let mesh = parse(text.as_bytes(), Path::new("q.ply")).unwrap();
        assert_eq!(mesh.positions.len(), 4);
        assert_eq!(mesh.faces, vec![[0, 1, 2], [0, 2, 3]]);
        assert!(mesh.colors.is_none());
    }

    #[test]
    fn rejects_truncated_data() {
        let dir = std::env::temp_dir().join(format!("bdis-ply-t-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("t.ply");
        write(&path, &sample()).unwrap();
        let bytes = std::fs::read(&path).unwrap();
        let e = parse(&bytes[..bytes.len() - 5], Path::new("t.ply")).unwrap_err().to_string();
        assert!(e.starts_with("t.ply: PLY: element `face` #0: data ends early"), "{e}");
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
