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
//! Optional per service (all validated):
//!
//! ```toml
//! liveness_s = 10          # no telemetry record (message or heartbeat) for this long: hung — stopped, then
//!                          # handled as a failure under the restart policy
//! handover = "keyframes"   # a replacement instance (swap, restart) starts with --standby and is activated after
//!                          # the last keyframe its downstream already has (the stereo service)
//! replacement_args = ["--resume"]   # for instances after the first (the mosaic resumes from its checkpoint)
//! essential = false        # (default true) when it fails for good the run goes on without it (the viewer)
//! [service.restart]
//! policy = "on-failure"    # never (default) | on-failure | always
//! max_restarts = 5         # at most this many restarts within window_s; one more failure fails the run
//! window_s = 60
//! backoff_initial_s = 0.5  # delay before the k-th restart in the window: initial · 2^(k−1), at most backoff_max_s
//! backoff_max_s = 10
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
    /// CPU core for the launcher itself (its telemetry drain, and forking replacements during swaps and restarts),
    /// so it stays off the tracker's core.
    #[serde(default)]
    pub launcher_core: Option<usize>,
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
            launcher_core: None,
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
    /// What happens when the process ends on its own.
    #[serde(default)]
    pub restart: RestartSpec,
    /// Seconds without any telemetry record (a message or a heartbeat) after which the process counts as hung.
    #[serde(default)]
    pub liveness_s: Option<f64>,
    /// How a replacement instance takes over (see the module documentation).
    #[serde(default)]
    pub handover: Option<Handover>,
    /// Extra arguments for every instance after the first (a restart, a swap), e.g. the mosaic's `--resume`.
    #[serde(default)]
    pub replacement_args: Vec<String>,
    /// Whether the run stands or falls with this service (the default). One that only watches (the viewer) is
    /// not: when it fails for good — out of restarts, or with `never` — the run goes on without it.
    #[serde(default = "essential_by_default")]
    pub essential: bool,
}

fn essential_by_default() -> bool {
    true
}

#[derive(Debug, Clone, Copy, Serialize, Deserialize, PartialEq, Eq, Default)]
#[serde(rename_all = "kebab-case")]
pub enum RestartPolicy {
    /// An ended process stays ended; a failure fails the run.
    #[default]
    Never,
    /// Restarted when it fails (non-zero exit, a signal, hung).
    OnFailure,
    /// Restarted whenever it ends while its upstream still runs (and when it fails).
    Always,
}

#[derive(Debug, Clone, Copy, Serialize, Deserialize, PartialEq, Eq)]
#[serde(rename_all = "kebab-case")]
pub enum Handover {
    /// Keyframe consumers (stereo): start in standby, resume after the last keyframe downstream has.
    Keyframes,
}

#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct RestartSpec {
    #[serde(default)]
    pub policy: RestartPolicy,
    #[serde(default = "default_max_restarts")]
    pub max_restarts: u32,
    #[serde(default = "default_window")]
    pub window_s: f64,
    #[serde(default = "default_backoff_initial")]
    pub backoff_initial_s: f64,
    #[serde(default = "default_backoff_max")]
    pub backoff_max_s: f64,
}

fn default_max_restarts() -> u32 {
    5
}
fn default_window() -> f64 {
    60.0
}
fn default_backoff_initial() -> f64 {
    0.5
}
fn default_backoff_max() -> f64 {
    10.0
}

impl Default for RestartSpec {
    fn default() -> Self {
        Self {
            policy: RestartPolicy::Never,
            max_restarts: default_max_restarts(),
            window_s: default_window(),
            backoff_initial_s: default_backoff_initial(),
            backoff_max_s: default_backoff_max(),
        }
    }
}

impl RestartSpec {
    /// The delay before a restart when `recent` restarts already happened within the window:
    /// `backoff_initial · 2^recent`, capped at `backoff_max`.
    pub fn backoff(&self, recent: usize) -> std::time::Duration {
        let factor = 2f64.powi(recent.min(30) as i32);
        std::time::Duration::from_secs_f64((self.backoff_initial_s * factor).min(self.backoff_max_s))
    }
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
        if let Some(core) = self.run.launcher_core
            && core >= cores
        {
            return Err(invalid(
                path,
                "run.launcher_core",
                format!("{core}, but this machine has cores 0..{}", cores - 1),
            ));
        }
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
            let r = &s.restart;
            for (k, v, lo) in [
                ("restart.window_s", r.window_s, 0.0),
                ("restart.backoff_initial_s", r.backoff_initial_s, 0.0),
                ("restart.backoff_max_s", r.backoff_max_s, 0.0),
            ] {
                if !(v.is_finite() && v > lo && v <= 86_400.0) {
                    return Err(invalid(path, &key(k), format!("must be in (0, 86400] seconds, found {v}")));
                }
            }
            if r.backoff_max_s < r.backoff_initial_s {
                return Err(invalid(
                    path,
                    &key("restart.backoff_max_s"),
                    format!("{} is below backoff_initial_s = {}", r.backoff_max_s, r.backoff_initial_s),
                ));
            }
            if r.max_restarts > 1000 {
                return Err(invalid(path, &key("restart.max_restarts"), format!("{} is over 1000", r.max_restarts)));
            }
            if let Some(l) = s.liveness_s
                && !(l.is_finite() && (0.5..=3600.0).contains(&l))
            {
                // Services send a heartbeat after 0.5 s of quiet, so a shorter deadline would kill idle ones.
                return Err(invalid(path, &key("liveness_s"), format!("must be in [0.5, 3600] seconds, found {l}")));
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
    fn every_shipped_launch_file_parses_or_names_the_core_this_machine_lacks() {
        let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("launch");
        let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
        let mut checked = 0;
        for entry in std::fs::read_dir(&dir).unwrap() {
            let path = entry.unwrap().path();
            if path.extension().is_none_or(|e| e != "toml") {
                continue;
            }
            let text = std::fs::read_to_string(&path).unwrap();
            // The most cores the file asks for, read from its text (the parse refuses a core this machine lacks).
            let needed = text
                .lines()
                .filter_map(|l| l.trim().strip_prefix("core = ").or_else(|| l.trim().strip_prefix("launcher_core = ")))
                .filter_map(|v| v.trim().parse::<usize>().ok())
                .max()
                .map_or(1, |c| c + 1);
            match LaunchFile::parse(&text, &path) {
                Ok(f) => assert!(!f.services.is_empty(), "{}", path.display()),
                Err(e) => {
                    assert!(needed > cores, "{}: {e}", path.display());
                    assert!(e.to_string().contains("but this machine has cores"), "{}: {e}", path.display());
                }
            }
            checked += 1;
        }
        assert!(checked >= 8, "{checked} launch files");
    }

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
    fn restart_policy_liveness_and_handover_are_validated() {
        let with = |extra: &str| LaunchFile::parse(&format!("{GOOD}{extra}"), Path::new("l.toml"));
        let f = with("liveness_s = 2.5\nhandover = \"keyframes\"\n[service.restart]\npolicy = \"on-failure\"\nmax_restarts = 3\nbackoff_initial_s = 0.1\nbackoff_max_s = 0.3\n").unwrap();
        let probe = &f.services[1];
        assert_eq!(probe.restart.policy, RestartPolicy::OnFailure);
        assert_eq!((probe.restart.max_restarts, probe.restart.window_s), (3, 60.0));
        assert_eq!((probe.liveness_s, probe.handover), (Some(2.5), Some(Handover::Keyframes)));
        assert_eq!(f.services[0].restart, RestartSpec::default());
        // Back-off doubles up to its cap.
        let b: Vec<f64> = (0..4).map(|k| probe.restart.backoff(k).as_secs_f64()).collect();
        assert!((b[0] - 0.1).abs() < 1e-9 && (b[1] - 0.2).abs() < 1e-9 && (b[2] - 0.3).abs() < 1e-9, "{b:?}");
        let err = |extra: &str| with(extra).unwrap_err().to_string();
        assert!(err("[service.restart]\npolicy = \"sometimes\"\n").contains("unknown variant `sometimes`"));
        assert!(err("[service.restart]\npolicie = \"always\"\n").contains("unknown field `policie`"));
        assert_eq!(
            err("[service.restart]\nbackoff_initial_s = 2\nbackoff_max_s = 1\n"),
            "l.toml: `service[1].restart.backoff_max_s`: 1 is below backoff_initial_s = 2"
        );
        assert_eq!(
            err("[service.restart]\nwindow_s = -1\n"),
            "l.toml: `service[1].restart.window_s`: must be in (0, 86400] seconds, found -1"
        );
        assert_eq!(
            err("liveness_s = 0.1\n"),
            "l.toml: `service[1].liveness_s`: must be in [0.5, 3600] seconds, found 0.1"
        );
        assert!(err("handover = \"frames\"\n").contains("unknown variant `frames`"));
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
