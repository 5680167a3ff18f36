//! Launch files (`launch/*.toml`): which processes a run starts, with what arguments, on which core.
//!
//! ```toml
//! [run]
//! name = "hamlyn6"
//!
//! [[service]]            # listed upstream first: started last, stopped first
//! name = "acquisition"
//! binary = "bdis-acquisition"
//! args = ["--sequence", "${LAUNCH_DIR}/../../shared/data/bdis/6", "--settings", "${LAUNCH_DIR}/settings/hamlyn6.yaml"]
//! core = 0
//!
//! [[service]]
//! name = "probe"
//! binary = "bdis-slam"
//! args = ["probe", "frames"]
//! core = 1
//! ```
//!
//! Everything is checked before anything starts: unknown keys, bad values, unknown `${VARIABLES}`, missing
//! binaries and cores this machine does not have are errors that name the key.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

#[derive(Debug, thiserror::Error)]
pub enum LaunchError {
    #[error("{path}: cannot read: {source}")]
    Io { path: PathBuf, source: std::io::Error },
    #[error("{at}: {message}")]
    Invalid { at: String, message: String },
}

fn invalid(path: &Path, key: &str, message: impl Into<String>) -> LaunchError {
    LaunchError::Invalid { at: format!("{}: `{key}`", path.display()), message: message.into() }
}

#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct RunSection {
    /// Names the run folder (`runs/<time>-<name>`).
    #[serde(default)]
    pub name: Option<String>,
    /// How long a service may take to open its ports and report ready.
    #[serde(default = "default_ready_timeout")]
    pub ready_timeout_s: f64,
    /// After every upstream service has ended, how long a service may take to finish on its own.
    #[serde(default = "default_drain_timeout")]
    pub drain_timeout_s: f64,
    /// Between SIGTERM and SIGKILL.
    #[serde(default = "default_stop_grace")]
    pub stop_grace_s: f64,
}

fn default_ready_timeout() -> f64 {
    20.0
}
fn default_drain_timeout() -> f64 {
    10.0
}
fn default_stop_grace() -> f64 {
    5.0
}

impl Default for RunSection {
    fn default() -> Self {
        Self {
            name: None,
            ready_timeout_s: default_ready_timeout(),
            drain_timeout_s: default_drain_timeout(),
            stop_grace_s: default_stop_grace(),
        }
    }
}

#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct ServiceSpec {
    /// Unique name in the run: telemetry, log file, `--name` of the process.
    pub name: String,
    /// A bdis-slam binary name (found next to the launcher), a path, or a program on PATH.
    pub binary: String,
    #[serde(default)]
    pub args: Vec<String>,
    /// CPU core to pin the process to.
    #[serde(default)]
    pub core: Option<usize>,
    /// Extra environment variables.
    #[serde(default)]
    pub env: BTreeMap<String, String>,
}

#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct LaunchFile {
    #[serde(default)]
    pub run: RunSection,
    /// Services in pipeline order, upstream first.
    #[serde(rename = "service")]
    pub services: Vec<ServiceSpec>,
}

/// A service ready to start: binary resolved, variables expanded.
#[derive(Debug, Clone)]
pub struct ResolvedService {
    pub spec: ServiceSpec,
    pub program: PathBuf,
    pub args: Vec<String>,
}

impl LaunchFile {
    pub fn load(path: &Path) -> Result<Self, LaunchError> {
        let text =
            std::fs::read_to_string(path).map_err(|source| LaunchError::Io { path: path.to_path_buf(), source })?;
        Self::parse(&text, path)
    }

    pub fn parse(text: &str, path: &Path) -> Result<Self, LaunchError> {
        let file: LaunchFile = toml::from_str(text).map_err(|e| {
            let line = e.span().map(|s| text[..s.start.min(text.len())].matches('\n').count() + 1);
            LaunchError::Invalid {
                at: match line {
                    Some(l) => format!("{}:{l}", path.display()),
                    None => path.display().to_string(),
                },
                message: e.message().trim().replace('\n', " "),
            }
        })?;
        file.validate(path)?;
        Ok(file)
    }

    fn validate(&self, path: &Path) -> Result<(), LaunchError> {
        if self.services.is_empty() {
            return Err(invalid(path, "service", "a launch file needs at least one [[service]]"));
        }
        for (key, v) in [
            ("run.ready_timeout_s", self.run.ready_timeout_s),
            ("run.drain_timeout_s", self.run.drain_timeout_s),
            ("run.stop_grace_s", self.run.stop_grace_s),
        ] {
            if !(v.is_finite() && v > 0.0 && v <= 3600.0) {
                return Err(invalid(path, key, format!("must be in (0, 3600] seconds, found {v}")));
            }
        }
        let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
        let mut names = std::collections::BTreeSet::new();
        for (i, s) in self.services.iter().enumerate() {
            let key = |k: &str| format!("service[{i}].{k}");
            if s.name.is_empty()
                || s.name.len() > 31
                || !s.name.chars().all(|c| c.is_ascii_alphanumeric() || c == '-' || c == '_')
            {
                return Err(invalid(path, &key("name"), format!("`{}`: use 1–31 characters [A-Za-z0-9_-]", s.name)));
            }
            if !names.insert(s.name.clone()) {
                return Err(invalid(path, &key("name"), format!("`{}` is used twice", s.name)));
            }
            if s.binary.is_empty() {
                return Err(invalid(path, &key("binary"), "must not be empty"));
            }
            if let Some(core) = s.core
                && core >= cores
            {
                return Err(invalid(
                    path,
                    &key("core"),
                    format!("{core}, but this machine has cores 0..{}", cores - 1),
                ));
            }
        }
        Ok(())
    }

    /// Resolves binaries and expands `${LAUNCH_DIR}`, `${RUN_DIR}` and environment variables in arguments.
    pub fn resolve(&self, path: &Path, run_dir: &Path) -> Result<Vec<ResolvedService>, LaunchError> {
        let launch_dir = path.parent().filter(|p| !p.as_os_str().is_empty()).unwrap_or(Path::new("."));
        let launch_dir = std::fs::canonicalize(launch_dir).unwrap_or_else(|_| launch_dir.to_path_buf());
        self.services
            .iter()
            .enumerate()
            .map(|(i, s)| {
                let program = find_binary(&s.binary).ok_or_else(|| {
                    invalid(
                        path,
                        &format!("service[{i}].binary"),
                        format!("`{}` not found (next to bdis-slam or on PATH)", s.binary),
                    )
                })?;
                let args = s
                    .args
                    .iter()
                    .map(|a| {
                        expand(a, &launch_dir, run_dir).map_err(|m| invalid(path, &format!("service[{i}].args"), m))
                    })
                    .collect::<Result<_, _>>()?;
                Ok(ResolvedService { spec: s.clone(), program, args })
            })
            .collect()
    }
}

/// Expands `${NAME}` in one argument.
fn expand(arg: &str, launch_dir: &Path, run_dir: &Path) -> Result<String, String> {
    let mut out = String::new();
    let mut rest = arg;
    while let Some(start) = rest.find("${") {
        out.push_str(&rest[..start]);
        let after = &rest[start + 2..];
        let end = after.find('}').ok_or_else(|| format!("`{arg}`: unclosed `${{`"))?;
        let name = &after[..end];
        let value = match name {
            "LAUNCH_DIR" => launch_dir.display().to_string(),
            "RUN_DIR" => run_dir.display().to_string(),
            _ => std::env::var(name).map_err(|_| format!("`{arg}`: unknown variable `{name}`"))?,
        };
        out.push_str(&value);
        rest = &after[end + 1..];
    }
    out.push_str(rest);
    Ok(out)
}

/// Finds a binary: a path as given, a bdis-slam binary next to the running launcher, or a program on PATH.
pub fn find_binary(name: &str) -> Option<PathBuf> {
    if name.contains('/') {
        let p = PathBuf::from(name);
        return p.is_file().then_some(p);
    }
    let exe = std::env::current_exe().ok()?;
    if exe.file_name().is_some_and(|n| n == name) {
        return Some(exe);
    }
    if let Some(sibling) = exe.parent().map(|d| d.join(name)).filter(|p| p.is_file()) {
        return Some(sibling);
    }
    std::env::var_os("PATH").and_then(|paths| std::env::split_paths(&paths).map(|d| d.join(name)).find(|p| p.is_file()))
}

#[cfg(test)]
mod tests {
    use super::*;

    const GOOD: &str = "[run]\nname = \"t\"\n[[service]]\nname = \"acquisition\"\nbinary = \"bdis-acquisition\"\nargs = [\"--x\"]\ncore = 0\n[[service]]\nname = \"probe\"\nbinary = \"bdis-slam\"\nargs = [\"probe\", \"frames\"]\n";

    #[test]
    fn parses_and_rejects_with_the_key() {
        let f = LaunchFile::parse(GOOD, Path::new("l.toml")).unwrap();
        assert_eq!(f.services.len(), 2);
        assert_eq!(f.run.stop_grace_s, 5.0);
        let e = LaunchFile::parse(&GOOD.replace("core = 0", "cores = 0"), Path::new("l.toml")).unwrap_err().to_string();
        assert!(e.starts_with("l.toml:7: unknown field `cores`"), "{e}");
        let e =
            LaunchFile::parse(&GOOD.replace("core = 0", "core = 999"), Path::new("l.toml")).unwrap_err().to_string();
        assert!(e.starts_with("l.toml: `service[0].core`: 999, but this machine has cores"), "{e}");
        let e = LaunchFile::parse(&GOOD.replace("\"probe\"\nbinary", "\"acquisition\"\nbinary"), Path::new("l.toml"))
            .unwrap_err()
            .to_string();
        assert_eq!(e, "l.toml: `service[1].name`: `acquisition` is used twice");
        let e = LaunchFile::parse(&format!("{GOOD}[run2]\n"), Path::new("l.toml")).unwrap_err().to_string();
        assert!(e.contains("unknown field `run2`"), "{e}");
    }

    #[test]
    fn expands_variables() {
        let l = Path::new("/l");
        let r = Path::new("/r");
        assert_eq!(expand("${LAUNCH_DIR}/a:${RUN_DIR}", l, r).unwrap(), "/l/a:/r");
        assert!(expand("${NO_SUCH_VAR_BDIS}", l, r).unwrap_err().contains("unknown variable `NO_SUCH_VAR_BDIS`"));
        assert!(expand("${LAUNCH_DIR", l, r).is_err());
    }
}
