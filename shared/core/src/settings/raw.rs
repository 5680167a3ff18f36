//! The reader of both syntaxes into one flat table of `Family.key → value` entries: OpenCV FileStorage YAML
//! (the subset ORB-SLAM2 and BDIS-SLAM settings use: scalars, quoted strings, `!!opencv-matrix` blocks) and the
//! project's TOML. Anything else is an error with its line.

use super::*;

/// One value of a settings file, as written.
#[derive(Debug, Clone, PartialEq)]
pub enum RawValue {
    /// A scalar as written (unquoted). Parsed to a number only when a typed field asks for one.
    Scalar(String),
    /// A quoted string.
    Text(String),
    /// An `!!opencv-matrix` block.
    Matrix { rows: usize, cols: usize, data: Vec<f64> },
}

/// An `!!opencv-matrix` as written: its shape, row-major values and line.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MatrixEntry<'a> {
    pub rows: usize,
    pub cols: usize,
    pub data: &'a [f64],
    pub line: Option<usize>,
}

#[derive(Debug, Clone, PartialEq)]
pub struct RawEntry {
    pub value: RawValue,
    pub line: Option<usize>,
}

/// The flat `Family.key → value` table of one settings file.
#[derive(Debug, Clone)]
pub struct RawSettings {
    pub path: PathBuf,
    pub entries: BTreeMap<String, RawEntry>,
}

pub(crate) fn syntax(path: &Path, line: usize, message: impl Into<String>) -> SettingsError {
    SettingsError::Syntax { at: Location { path: path.to_path_buf(), line: Some(line) }, message: message.into() }
}

/// Removes a trailing `# comment` that is outside quotes.
pub(crate) fn strip_comment(line: &str) -> &str {
    let mut in_quotes = false;
    for (i, c) in line.char_indices() {
        match c {
            '"' => in_quotes = !in_quotes,
            '#' if !in_quotes => return &line[..i],
            _ => {}
        }
    }
    line
}

pub(crate) fn unquote(s: &str) -> Option<&str> {
    let s = s.trim();
    if s.len() >= 2 && ((s.starts_with('"') && s.ends_with('"')) || (s.starts_with('\'') && s.ends_with('\''))) {
        Some(&s[1..s.len() - 1])
    } else {
        None
    }
}

/// Splits `key: value` (OpenCV also writes `data:[...]` without the space).
pub(crate) fn split_key_value(text: &str) -> Option<(&str, &str)> {
    let colon = text.find(':')?;
    let key = text[..colon].trim();
    if key.is_empty() || key.contains(char::is_whitespace) {
        return None;
    }
    Some((key, text[colon + 1..].trim()))
}

impl RawSettings {
    /// Reads a settings file, choosing the syntax by its extension (`.yaml`/`.yml` or `.toml`).
    pub fn load(path: &Path) -> Result<Self, SettingsError> {
        let text =
            std::fs::read_to_string(path).map_err(|detail| SettingsError::Io { path: path.to_path_buf(), detail })?;
        match path.extension().and_then(|e| e.to_str()).map(str::to_ascii_lowercase).as_deref() {
            Some("yaml") | Some("yml") => Self::parse_opencv_yaml(&text, path),
            Some("toml") => Self::parse_toml(&text, path),
            _ => Err(SettingsError::Format { path: path.to_path_buf() }),
        }
    }

    /// Parses the OpenCV FileStorage YAML subset used by ORB-SLAM2 and BDIS-SLAM settings files.
    pub fn parse_opencv_yaml(text: &str, path: &Path) -> Result<Self, SettingsError> {
        let mut entries = BTreeMap::new();
        let lines: Vec<&str> = text.lines().collect();
        let mut i = 0;
        let mut seen_content = false;
        while i < lines.len() {
            let line_no = i + 1;
            let raw = lines[i];
            i += 1;
            let line = strip_comment(raw).trim_end();
            if line.trim().is_empty() {
                continue;
            }
            if !seen_content {
                seen_content = true;
                if line.trim().starts_with("%YAML") {
                    continue;
                }
                return Err(syntax(path, line_no, "not an OpenCV settings file: the first line must be `%YAML:1.0`"));
            }
            if line.trim() == "---" {
                continue;
            }
            if line.starts_with(char::is_whitespace) {
                return Err(syntax(path, line_no, format!("unexpected indented line `{}`", line.trim())));
            }
            let Some((key, value)) = split_key_value(line) else {
                return Err(syntax(path, line_no, format!("expected `key: value`, found `{}`", line.trim())));
            };
            let value = if value.starts_with("!!opencv-matrix") {
                let (matrix, next) = parse_matrix_block(&lines, i, path, key)?;
                i = next;
                matrix
            } else if value.is_empty() {
                return Err(syntax(path, line_no, format!("`{key}` has no value (nested maps are not supported)")));
            } else if value.starts_with('[') || value.starts_with('{') || value.starts_with('!') || value == "|" {
                return Err(syntax(path, line_no, format!("`{key}`: unsupported value `{value}`")));
            } else if let Some(text) = unquote(value) {
                RawValue::Text(text.to_string())
            } else {
                RawValue::Scalar(value.to_string())
            };
            if entries.insert(key.to_string(), RawEntry { value, line: Some(line_no) }).is_some() {
                return Err(syntax(path, line_no, format!("`{key}` is given twice")));
            }
        }
        if !seen_content {
            return Err(syntax(path, 1, "the file is empty"));
        }
        Ok(Self { path: path.to_path_buf(), entries })
    }

    /// Parses the project's TOML settings: tables named like the YAML families (`[Camera]`, `[ORBextractor]`,
    /// `[BDISparam]`, `[Viewer3D]`) and top-level keys (`ThDepth`).
    pub fn parse_toml(text: &str, path: &Path) -> Result<Self, SettingsError> {
        let table: toml::Table = text.parse().map_err(|e: toml::de::Error| {
            let line = e.span().map(|span| text[..span.start.min(text.len())].matches('\n').count() + 1);
            SettingsError::Syntax { at: Location { path: path.to_path_buf(), line }, message: e.message().to_string() }
        })?;
        let mut entries = BTreeMap::new();
        fn scalar(path: &Path, key: &str, v: &toml::Value) -> Result<RawValue, SettingsError> {
            Ok(match v {
                toml::Value::Integer(i) => RawValue::Scalar(i.to_string()),
                toml::Value::Float(f) => RawValue::Scalar(f.to_string()),
                toml::Value::Boolean(b) => RawValue::Scalar(if *b { "1".into() } else { "0".into() }),
                toml::Value::String(s) => RawValue::Text(s.clone()),
                _ => return Err(SettingsError::value(path, None, key, "expected a number, a boolean or a string")),
            })
        }
        for (family, value) in &table {
            match value {
                toml::Value::Table(inner) => {
                    for (name, v) in inner {
                        let key = format!("{family}.{name}");
                        let raw = scalar(path, &key, v)?;
                        entries.insert(key, RawEntry { value: raw, line: None });
                    }
                }
                v => {
                    entries.insert(family.clone(), RawEntry { value: scalar(path, family, v)?, line: None });
                }
            }
        }
        Ok(Self { path: path.to_path_buf(), entries })
    }

    /// The `!!opencv-matrix` at `key`; `None` when the key is absent.
    pub fn matrix(&self, key: &str) -> Result<Option<MatrixEntry<'_>>, SettingsError> {
        let Some(entry) = self.entries.get(key) else { return Ok(None) };
        match &entry.value {
            RawValue::Matrix { rows, cols, data } => {
                Ok(Some(MatrixEntry { rows: *rows, cols: *cols, data: data.as_slice(), line: entry.line }))
            }
            _ => Err(SettingsError::value(&self.path, entry.line, key, "expected an `!!opencv-matrix`")),
        }
    }

    /// The number at `key` with its line; `None` when the key is absent.
    pub fn number(&self, key: &str) -> Result<Option<(f64, Option<usize>)>, SettingsError> {
        let Some(entry) = self.entries.get(key) else { return Ok(None) };
        let text = match &entry.value {
            RawValue::Scalar(s) => s.as_str(),
            RawValue::Text(s) => {
                return Err(SettingsError::value(
                    &self.path,
                    entry.line,
                    key,
                    format!("expected a number, found the string \"{s}\""),
                ));
            }
            RawValue::Matrix { .. } => {
                return Err(SettingsError::value(&self.path, entry.line, key, "expected a number, found a matrix"));
            }
        };
        // Only plain decimal numbers: OpenCV refuses `2055.77s`, and so do we. `.nan`/`inf` spellings parse
        // here and are rejected by the finiteness check below with a clearer message.
        let parsed = match text {
            ".nan" | ".NaN" | ".NAN" | "nan" | "NaN" => f64::NAN,
            ".inf" | ".Inf" | "inf" | "+.inf" => f64::INFINITY,
            "-.inf" | "-.Inf" | "-inf" => f64::NEG_INFINITY,
            _ => text
                .parse::<f64>()
                .map_err(|_| SettingsError::value(&self.path, entry.line, key, format!("`{text}` is not a number")))?,
        };
        if !parsed.is_finite() {
            return Err(SettingsError::value(
                &self.path,
                entry.line,
                key,
                format!("must be a finite number, found `{text}`"),
            ));
        }
        Ok(Some((parsed, entry.line)))
    }
}

/// Reads the rows/cols/dt/data lines of an `!!opencv-matrix` block starting at line index `start`.
pub(crate) fn parse_matrix_block(
    lines: &[&str],
    start: usize,
    path: &Path,
    key: &str,
) -> Result<(RawValue, usize), SettingsError> {
    let mut rows = None;
    let mut cols = None;
    let mut data: Option<Vec<f64>> = None;
    let mut i = start;
    while i < lines.len() {
        let line = strip_comment(lines[i]);
        if line.trim().is_empty() {
            i += 1;
            continue;
        }
        if !line.starts_with(char::is_whitespace) {
            break;
        }
        let line_no = i + 1;
        i += 1;
        let Some((field, value)) = split_key_value(line.trim()) else {
            return Err(syntax(path, line_no, format!("`{key}`: expected `field: value` inside the matrix")));
        };
        match field {
            "rows" | "cols" => {
                let n: usize = value
                    .parse()
                    .map_err(|_| syntax(path, line_no, format!("`{key}.{field}`: `{value}` is not a count")))?;
                if field == "rows" { rows = Some(n) } else { cols = Some(n) }
            }
            "dt" => {}
            "data" => {
                // The list may span several lines up to the closing bracket.
                let mut text = value.to_string();
                while !text.contains(']') && i < lines.len() {
                    text.push(' ');
                    text.push_str(strip_comment(lines[i]).trim());
                    i += 1;
                }
                let inner = text
                    .trim()
                    .strip_prefix('[')
                    .and_then(|t| t.split(']').next())
                    .ok_or_else(|| syntax(path, line_no, format!("`{key}.data` must be a `[ ... ]` list")))?;
                let mut values = Vec::new();
                for item in inner.split(',').map(str::trim).filter(|s| !s.is_empty()) {
                    let v: f64 = item
                        .parse()
                        .map_err(|_| syntax(path, line_no, format!("`{key}.data`: `{item}` is not a number")))?;
                    if !v.is_finite() {
                        return Err(syntax(path, line_no, format!("`{key}.data`: `{item}` is not finite")));
                    }
                    values.push(v);
                }
                data = Some(values);
            }
            other => return Err(syntax(path, line_no, format!("`{key}`: unknown matrix field `{other}`"))),
        }
    }
    let (Some(rows), Some(cols), Some(data)) = (rows, cols, data) else {
        return Err(syntax(path, start, format!("`{key}`: an opencv-matrix needs rows, cols and data")));
    };
    if rows * cols != data.len() {
        return Err(syntax(path, start, format!("`{key}`: {rows}×{cols} matrix with {} values", data.len())));
    }
    Ok((RawValue::Matrix { rows, cols, data }, i))
}
