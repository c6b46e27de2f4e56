//! The supervisor's core: the mesh file (which services run, with which arguments, and how they are
//! restarted) and the restart policy. Plain data and decisions; `main.rs` runs the processes.
//!
//! A mesh file (`config/sim-mesh.toml`, `config/vehicle.toml`):
//!
//! ```toml
//! [mesh]
//! endpoint = "sim"                      # passed to every service as --endpoint
//! config = "bluerov2"                   # the services' config directory, beside this file (it wins
//!                                       # over the supervisor's --config)
//! stop_when = ["simulator", "monitor"]  # done once all of these have exited successfully
//! [restart]
//! enabled = false                       # restart a service that dies (with backoff, up to a limit)
//! [[service]]
//! name = "simulator"
//! args = ["--episodes", "{episodes}"]   # {key} comes from `supervisor --set key=value`
//! [[service]]
//! name = "shore-link"
//! binary = "{shore_link}"               # the program: a name in the binaries' directory, or a
//!                                       # path (with a `/`, relative to the working directory)
//! only_if = "{shore_link}"
//! args = ["vehicle", "{auth}"]          # an argument that is only an empty placeholder is left out
//! [[service]]
//! name = "recorder"
//! only_if = "{record}"                  # runs only when this is not empty
//! observer = true                       # starts first (the others once it is ready), stops last
//! scheduling = "idle"                   # runs only on a CPU nothing else wants (default "normal")
//! cpus = "1"                            # may run only on these CPUs (`0-1,3`; default: any)
//! args = ["--out", "{record}"]
//! ```

use runtime::process::{Placement, Scheduling};
use serde::Deserialize;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::time::Duration;

/// A mesh of services.
#[derive(Clone, Debug, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MeshFile {
    pub mesh: MeshParams,
    #[serde(default)]
    pub restart: RestartPolicy,
    pub service: Vec<ServiceSpec>,
}

#[derive(Clone, Debug, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MeshParams {
    pub endpoint: String,
    /// The mesh has done its job once all of these services have exited with success (empty: run
    /// until SIGINT/SIGTERM).
    #[serde(default)]
    pub stop_when: Vec<String>,
    /// Placeholder values used when the command line does not set them.
    #[serde(default)]
    pub defaults: BTreeMap<String, String>,
    /// The configuration directory the services read, relative to the mesh file's directory
    /// (`config/bluerov2.toml` names `config/bluerov2` with `config = "bluerov2"`); it wins over the
    /// supervisor's `--config`. None: the supervisor's `--config`.
    #[serde(default)]
    pub config: Option<PathBuf>,
}

/// How dead services are restarted.
#[derive(Clone, Debug, PartialEq, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct RestartPolicy {
    pub enabled: bool,
    /// Restarts of one service allowed within `window_s`; one more and the mesh is stopped.
    pub max_restarts: u32,
    pub window_s: f64,
    /// The delay before a restart doubles with each recent restart, from this up to `backoff_max_ms`.
    pub backoff_initial_ms: u64,
    pub backoff_max_ms: u64,
}

impl Default for RestartPolicy {
    fn default() -> Self {
        RestartPolicy {
            enabled: false,
            max_restarts: 5,
            window_s: 60.0,
            backoff_initial_ms: 200,
            backoff_max_ms: 5000,
        }
    }
}

impl RestartPolicy {
    /// The delay before the next restart of a service that was restarted at `recent` (seconds ago,
    /// any order), or `None` when it has used up its restarts.
    pub fn next_delay(&self, recent: &[f64]) -> Option<Duration> {
        let n = recent.iter().filter(|&&ago| ago <= self.window_s).count() as u32;
        if !self.enabled || n >= self.max_restarts {
            return None;
        }
        let ms = self
            .backoff_initial_ms
            .saturating_mul(1u64 << n.min(20))
            .min(self.backoff_max_ms);
        Some(Duration::from_millis(ms))
    }
}

/// One service of the mesh.
#[derive(Clone, Debug, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ServiceSpec {
    pub name: String,
    /// The program (default: `name`): a name is looked up in the binaries' directory, a path (one
    /// with a `/`: a program built elsewhere, such as the shore link's own workspace) is taken as it
    /// is, relative to the working directory; may be a placeholder.
    pub binary: Option<String>,
    #[serde(default)]
    pub args: Vec<String>,
    /// Overrides `[restart] enabled` for this service.
    pub restart: Option<bool>,
    /// The service runs only when this text, placeholders filled, is not empty (`"{record}"`: only
    /// when a file to record to is given).
    pub only_if: Option<String>,
    /// It watches the others (the flight recorder): it is started first and the others only once
    /// it says it is ready, and stopped last, so it sees the mesh's first and last messages.
    #[serde(default)]
    pub observer: bool,
    /// Its scheduling class: `normal`, or `idle` (only on a CPU nothing else wants); may be a
    /// placeholder.
    pub scheduling: Option<String>,
    /// The CPUs it may run on, `taskset -c` style (`0`, `0-1,3`; empty: any); may be a
    /// placeholder.
    pub cpus: Option<String>,
}

/// Why a mesh file cannot be used; names the file.
#[derive(Debug, thiserror::Error)]
pub enum MeshError {
    #[error("cannot read mesh file {}: {source}", file.display())]
    Read {
        file: PathBuf,
        source: std::io::Error,
    },
    #[error("in mesh file {}: {source}", file.display())]
    Parse {
        file: PathBuf,
        source: Box<toml::de::Error>,
    },
    #[error("in mesh file {}: {message}", file.display())]
    Invalid { file: PathBuf, message: String },
    #[error("service `{service}`: {} does not exist ({hint})", path.display())]
    NoProgram {
        service: String,
        path: PathBuf,
        hint: &'static str,
    },
}

impl MeshFile {
    /// The configuration directory this mesh names ([`MeshParams::config`]), resolved against the
    /// directory of the mesh file at `path`.
    pub fn config_dir(&self, path: &Path) -> Option<PathBuf> {
        let dir = self.mesh.config.as_ref()?;
        Some(path.parent().unwrap_or(Path::new(".")).join(dir))
    }

    pub fn load(path: &Path) -> Result<MeshFile, MeshError> {
        let text = std::fs::read_to_string(path).map_err(|source| MeshError::Read {
            file: path.to_owned(),
            source,
        })?;
        Self::parse(&text, path)
    }

    pub fn parse(text: &str, path: &Path) -> Result<MeshFile, MeshError> {
        let mesh: MeshFile = toml::from_str(text).map_err(|source| MeshError::Parse {
            file: path.to_owned(),
            source: Box::new(source),
        })?;
        let invalid = |message: String| MeshError::Invalid {
            file: path.to_owned(),
            message,
        };
        mesh.mesh
            .endpoint
            .parse::<messages::Endpoint>()
            .map_err(|e| invalid(format!("mesh.endpoint: {e}")))?;
        if mesh.service.is_empty() {
            return Err(invalid("no [[service]]".into()));
        }
        for (i, s) in mesh.service.iter().enumerate() {
            if mesh.service[..i].iter().any(|o| o.name == s.name) {
                return Err(invalid(format!("service `{}` is listed twice", s.name)));
            }
        }
        for name in &mesh.mesh.stop_when {
            let Some(s) = mesh.service.iter().find(|s| &s.name == name) else {
                return Err(invalid(format!(
                    "mesh.stop_when names `{name}`, which is not a [[service]]"
                )));
            };
            if s.only_if.is_some() {
                return Err(invalid(format!(
                    "mesh.stop_when names `{name}`, which may not run (it has `only_if`)"
                )));
            }
        }
        Ok(mesh)
    }

    /// Each service's program and arguments, placeholders filled from `vars` (then the file's
    /// defaults), `--endpoint` added; a service whose `only_if` is empty is left out.
    pub fn commands(
        &self,
        vars: &BTreeMap<String, String>,
        path: &Path,
    ) -> Result<Vec<ServiceCommand>, MeshError> {
        let mut all = self.mesh.defaults.clone();
        all.extend(vars.iter().map(|(k, v)| (k.clone(), v.clone())));
        let fill = |service: &str, text: &str| {
            substitute(text, &all).map_err(|key| MeshError::Invalid {
                file: path.to_owned(),
                message: format!(
                    "service `{service}`: no value for `{{{key}}}` (pass --set {key}=VALUE)"
                ),
            })
        };
        let mut out = Vec::new();
        for s in &self.service {
            if let Some(cond) = &s.only_if
                && fill(&s.name, cond)?.trim().is_empty()
            {
                continue;
            }
            out.push(self.command(s, &fill, path)?);
        }
        Ok(out)
    }

    fn command(
        &self,
        s: &ServiceSpec,
        fill: &impl Fn(&str, &str) -> Result<String, MeshError>,
        path: &Path,
    ) -> Result<ServiceCommand, MeshError> {
        let mut args = vec!["--endpoint".to_owned(), self.mesh.endpoint.clone()];
        for a in &s.args {
            let arg = fill(&s.name, a)?;
            // An argument that is only an empty placeholder is left out: optional flags.
            if !arg.is_empty() {
                args.push(arg);
            }
        }
        let binary = fill(&s.name, s.binary.as_deref().unwrap_or(&s.name))?;
        if binary.trim().is_empty() {
            return Err(MeshError::Invalid {
                file: path.to_owned(),
                message: format!(
                    "service `{}`: binary `{}` is empty",
                    s.name,
                    s.binary.as_deref().unwrap_or_default()
                ),
            });
        }
        Ok(ServiceCommand {
            name: s.name.clone(),
            binary,
            args,
            restart: s.restart.unwrap_or(self.restart.enabled),
            observer: s.observer,
            placement: self.placement(s, fill, path)?,
        })
    }

    /// The service's scheduling class and CPUs, placeholders filled, checked against this machine.
    fn placement(
        &self,
        s: &ServiceSpec,
        fill: &impl Fn(&str, &str) -> Result<String, MeshError>,
        path: &Path,
    ) -> Result<Placement, MeshError> {
        let invalid = |key: &str, why: String| MeshError::Invalid {
            file: path.to_owned(),
            message: format!("service `{}`: {key}: {why}", s.name),
        };
        let scheduling = match &s.scheduling {
            None => Scheduling::Normal,
            Some(text) => fill(&s.name, text)?
                .parse()
                .map_err(|why| invalid("scheduling", why))?,
        };
        let cpus = match &s.cpus {
            None => Vec::new(),
            Some(text) => runtime::process::parse_cpus(&fill(&s.name, text)?)
                .map_err(|why| invalid("cpus", why))?,
        };
        let placement = Placement { scheduling, cpus };
        placement.check().map_err(|why| invalid("cpus", why))?;
        Ok(placement)
    }
}

/// A service ready to start.
#[derive(Clone, Debug, PartialEq)]
pub struct ServiceCommand {
    pub name: String,
    /// The program's name in the binaries' directory, or its path (see [`ServiceSpec::binary`]).
    pub binary: String,
    pub args: Vec<String>,
    pub restart: bool,
    /// Started first and stopped last (see [`ServiceSpec::observer`]).
    pub observer: bool,
    pub placement: Placement,
}

impl ServiceCommand {
    /// The program to run: [`ServiceCommand::binary`] in `bin_dir`, or where it says when it is a
    /// path (made absolute against the working directory, so the log shows where it is); an error
    /// naming the service and the path when there is no such file.
    pub fn program(&self, bin_dir: &Path) -> Result<PathBuf, MeshError> {
        let (path, hint) = if self.binary.contains('/') {
            (
                std::path::absolute(&self.binary).unwrap_or_else(|_| PathBuf::from(&self.binary)),
                "its `binary` is this path: build that program first",
            )
        } else {
            (
                bin_dir.join(&self.binary),
                "build with cargo build --release",
            )
        };
        if !path.is_file() {
            return Err(MeshError::NoProgram {
                service: self.name.clone(),
                path,
                hint,
            });
        }
        Ok(path)
    }
}

/// Replaces every `{key}` in `text`; the first key without a value is the error.
pub fn substitute(text: &str, vars: &BTreeMap<String, String>) -> Result<String, String> {
    let mut out = String::new();
    let mut rest = text;
    while let Some(open) = rest.find('{') {
        let Some(close) = rest[open..].find('}') else {
            break;
        };
        let key = &rest[open + 1..open + close];
        out.push_str(&rest[..open]);
        out.push_str(vars.get(key).ok_or_else(|| key.to_owned())?);
        rest = &rest[open + close + 1..];
    }
    out.push_str(rest);
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    const MESH: &str = r#"
[mesh]
endpoint = "sim"
stop_when = ["simulator"]
defaults = { eyes = "ideal", record = "" }
[restart]
enabled = true
[[service]]
name = "simulator"
args = ["--episodes", "{episodes}"]
restart = false
[[service]]
name = "camera"
args = ["--eyes", "{eyes}"]
[[service]]
name = "recorder"
only_if = "{record}"
observer = true
args = ["--out", "{record}"]
"#;

    #[test]
    fn a_mesh_names_its_config_directory_beside_itself() {
        let mesh = MeshFile::parse(MESH, Path::new("config/sim.toml")).unwrap();
        assert_eq!(mesh.config_dir(Path::new("config/sim.toml")), None);
        let text = MESH.replace(
            "endpoint = \"sim\"",
            "endpoint = \"sim\"\nconfig = \"bluerov2\"",
        );
        let mesh = MeshFile::parse(&text, Path::new("config/b.toml")).unwrap();
        assert_eq!(
            mesh.config_dir(Path::new("config/b.toml")),
            Some(PathBuf::from("config/bluerov2"))
        );
    }

    #[test]
    fn placements_fill_placeholders_and_name_what_is_wrong() {
        let text = r#"
[mesh]
endpoint = "sim"
defaults = { cpus = "0", class = "idle" }
[[service]]
name = "camera"
cpus = "{cpus}"
[[service]]
name = "recorder"
scheduling = "{class}"
[[service]]
name = "monitor"
"#;
        let mesh = MeshFile::parse(text, Path::new("m.toml")).unwrap();
        let cmds = mesh
            .commands(&BTreeMap::new(), Path::new("m.toml"))
            .unwrap();
        assert_eq!(cmds[0].placement.cpus, [0]);
        assert_eq!(cmds[0].placement.scheduling, Scheduling::Normal);
        assert_eq!(cmds[1].placement.scheduling, Scheduling::Idle);
        assert!(cmds[1].placement.cpus.is_empty());
        assert_eq!(cmds[2].placement, Placement::default());
        // Emptied from the command line: any CPU, the normal class.
        let free = BTreeMap::from([
            ("cpus".to_owned(), String::new()),
            ("class".to_owned(), "normal".to_owned()),
        ]);
        let cmds = mesh.commands(&free, Path::new("m.toml")).unwrap();
        assert!(cmds.iter().all(|c| c.placement == Placement::default()));
        for (key, value, want) in [
            (
                "class",
                "fifo",
                "service `recorder`: scheduling: `fifo` is not",
            ),
            (
                "cpus",
                "9999",
                "service `camera`: cpus: this machine has CPUs 0 to",
            ),
            (
                "cpus",
                "x",
                "service `camera`: cpus: `x` in `x` is not a CPU number",
            ),
        ] {
            let bad = BTreeMap::from([(key.to_owned(), value.to_owned())]);
            let e = mesh
                .commands(&bad, Path::new("m.toml"))
                .unwrap_err()
                .to_string();
            assert!(e.contains("m.toml") && e.contains(want), "{e}");
        }
    }

    #[test]
    fn commands_fill_placeholders_and_restart_policy() {
        let mesh = MeshFile::parse(MESH, Path::new("m.toml")).unwrap();
        let vars = BTreeMap::from([("episodes".to_owned(), "20".to_owned())]);
        let cmds = mesh.commands(&vars, Path::new("m.toml")).unwrap();
        assert_eq!(cmds[0].args, ["--endpoint", "sim", "--episodes", "20"]);
        assert!(!cmds[0].restart);
        assert_eq!(cmds[1].args, ["--endpoint", "sim", "--eyes", "ideal"]);
        assert!(cmds[1].restart);
        assert!(
            !mesh.service[2].args.is_empty() && cmds.len() == 2,
            "the recorder is left out while {{record}} has no value: {cmds:?}"
        );
        let recording = BTreeMap::from([
            ("episodes".to_owned(), "5".to_owned()),
            ("record".to_owned(), "dive.mcap".to_owned()),
        ]);
        let cmds = mesh.commands(&recording, Path::new("m.toml")).unwrap();
        assert_eq!(cmds.len(), 3);
        assert_eq!(cmds[2].args, ["--endpoint", "sim", "--out", "dive.mcap"]);
        assert!(cmds[2].observer && !cmds[0].observer);
        let optional = BTreeMap::from([
            ("episodes".to_owned(), "5".to_owned()),
            ("eyes".to_owned(), String::new()),
        ]);
        let cmds = mesh.commands(&optional, Path::new("m.toml")).unwrap();
        assert_eq!(
            cmds[1].args,
            ["--endpoint", "sim", "--eyes"],
            "an empty placeholder is left out"
        );
        let err = mesh
            .commands(&BTreeMap::new(), Path::new("m.toml"))
            .unwrap_err();
        assert!(
            err.to_string().contains("{episodes}") && err.to_string().contains("m.toml"),
            "{err}"
        );
    }

    #[test]
    fn a_program_is_a_name_in_the_bin_dir_or_a_path_from_a_placeholder() {
        let text = r#"
[mesh]
endpoint = "vehicle"
defaults = { link = "", auth = "" }
[[service]]
name = "camera"
[[service]]
name = "shore-link"
binary = "{link}"
only_if = "{link}"
args = ["vehicle", "{auth}"]
"#;
        let file = Path::new("m.toml");
        let mesh = MeshFile::parse(text, file).unwrap();
        let dir = tempfile::tempdir().unwrap();
        let bin_dir = dir.path().join("bin");
        std::fs::create_dir(&bin_dir).unwrap();
        std::fs::write(bin_dir.join("camera"), "").unwrap();
        let elsewhere = dir.path().join("other/target/release");
        std::fs::create_dir_all(&elsewhere).unwrap();
        std::fs::write(elsewhere.join("shore-link"), "").unwrap();

        // The placeholder empty: no link; the others are found in the bin dir by name.
        let cmds = mesh.commands(&BTreeMap::new(), file).unwrap();
        assert_eq!(cmds.len(), 1);
        assert_eq!(cmds[0].binary, "camera");
        assert_eq!(cmds[0].program(&bin_dir).unwrap(), bin_dir.join("camera"));

        // A path, absolute: taken as it is, not looked up in the bin dir.
        let link = elsewhere.join("shore-link").display().to_string();
        let vars = BTreeMap::from([
            ("link".to_owned(), link.clone()),
            ("auth".to_owned(), "--insecure".to_owned()),
        ]);
        let cmds = mesh.commands(&vars, file).unwrap();
        assert_eq!(cmds[1].binary, link);
        assert_eq!(
            cmds[1].args,
            ["--endpoint", "vehicle", "vehicle", "--insecure"]
        );
        assert_eq!(
            cmds[1].program(&bin_dir).unwrap(),
            elsewhere.join("shore-link")
        );

        // A relative path: against the working directory, made absolute.
        let cwd = std::env::current_dir().unwrap();
        let here = tempfile::tempdir_in(&cwd).unwrap();
        std::fs::write(here.path().join("shore-link"), "").unwrap();
        let relative = here
            .path()
            .strip_prefix(&cwd)
            .unwrap()
            .join("shore-link")
            .display()
            .to_string();
        assert!(relative.contains('/') && !relative.starts_with('/'));
        let vars = BTreeMap::from([("link".to_owned(), relative)]);
        let cmds = mesh.commands(&vars, file).unwrap();
        assert_eq!(cmds[1].args, ["--endpoint", "vehicle", "vehicle"]);
        assert_eq!(
            cmds[1].program(&bin_dir).unwrap(),
            here.path().join("shore-link")
        );

        // No such program: the error names the service and the path.
        let missing = elsewhere.join("shore-linc").display().to_string();
        let vars = BTreeMap::from([("link".to_owned(), missing.clone())]);
        let cmds = mesh.commands(&vars, file).unwrap();
        let e = cmds[1].program(&bin_dir).unwrap_err().to_string();
        assert!(
            e.contains("service `shore-link`")
                && e.contains(&missing)
                && e.contains("does not exist"),
            "{e}"
        );
        let gone = bin_dir.join("camera");
        std::fs::remove_file(&gone).unwrap();
        let e = cmds[0].program(&bin_dir).unwrap_err().to_string();
        assert!(
            e.contains("service `camera`") && e.contains(&gone.display().to_string()),
            "{e}"
        );
        // A directory is no program.
        let vars = BTreeMap::from([("link".to_owned(), elsewhere.display().to_string())]);
        let cmds = mesh.commands(&vars, file).unwrap();
        assert!(cmds[1].program(&bin_dir).is_err());
    }

    #[test]
    fn a_binary_that_fills_empty_is_refused_by_name() {
        let text = r#"
[mesh]
endpoint = "vehicle"
[[service]]
name = "shore-link"
binary = "{link}"
"#;
        let mesh = MeshFile::parse(text, Path::new("m.toml")).unwrap();
        let vars = BTreeMap::from([("link".to_owned(), String::new())]);
        let e = mesh
            .commands(&vars, Path::new("m.toml"))
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("m.toml") && e.contains("service `shore-link`") && e.contains("{link}"),
            "{e}"
        );
        let e = mesh
            .commands(&BTreeMap::new(), Path::new("m.toml"))
            .unwrap_err()
            .to_string();
        assert!(e.contains("--set link=VALUE"), "{e}");
    }

    #[test]
    fn bad_files_are_refused_by_name() {
        let bad = MESH.replace("stop_when = [\"simulator\"]", "stop_when = [\"simulatr\"]");
        let err = MeshFile::parse(&bad, Path::new("x.toml"))
            .unwrap_err()
            .to_string();
        assert!(err.contains("x.toml") && err.contains("simulatr"), "{err}");
        let err = MeshFile::parse(
            &MESH.replace("args = [\"--eyes\"", "argz = [\"--eyes\""),
            Path::new("x.toml"),
        )
        .unwrap_err()
        .to_string();
        assert!(err.contains("argz"), "{err}");
        let err = MeshFile::parse(&MESH.replace("\"sim\"", "\"boat\""), Path::new("x.toml"))
            .unwrap_err()
            .to_string();
        assert!(err.contains("endpoint"), "{err}");
        let err = MeshFile::parse(
            &MESH.replace("stop_when = [\"simulator\"]", "stop_when = [\"recorder\"]"),
            Path::new("x.toml"),
        )
        .unwrap_err()
        .to_string();
        assert!(err.contains("only_if"), "{err}");
    }

    #[test]
    fn restarts_back_off_and_stop_at_the_limit() {
        let p = RestartPolicy {
            enabled: true,
            max_restarts: 3,
            window_s: 60.0,
            backoff_initial_ms: 100,
            backoff_max_ms: 300,
        };
        assert_eq!(p.next_delay(&[]), Some(Duration::from_millis(100)));
        assert_eq!(p.next_delay(&[1.0]), Some(Duration::from_millis(200)));
        assert_eq!(p.next_delay(&[1.0, 2.0]), Some(Duration::from_millis(300)));
        assert_eq!(p.next_delay(&[1.0, 2.0, 3.0]), None);
        // Old restarts fall out of the window.
        assert_eq!(
            p.next_delay(&[100.0, 200.0, 300.0]),
            Some(Duration::from_millis(100))
        );
        assert_eq!(
            RestartPolicy::default().next_delay(&[]),
            None,
            "off by default"
        );
    }

    #[test]
    fn substitution() {
        let vars = BTreeMap::from([("a".to_owned(), "1".to_owned())]);
        assert_eq!(substitute("x{a}y{a}", &vars).unwrap(), "x1y1");
        assert_eq!(substitute("plain", &vars).unwrap(), "plain");
        assert_eq!(substitute("{b}", &vars).unwrap_err(), "b");
    }
}
