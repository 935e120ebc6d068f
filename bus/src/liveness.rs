//! Which processes of a run are alive, cleanup after dead ones, and removal of leftovers.

use std::path::{Path, PathBuf};

use iceoryx2::config::Config;
use iceoryx2::node::{NodeCleanupFailure, NodeState, NodeView};
use iceoryx2::prelude::*;

use crate::config::iceoryx_config_for_prefix;
use crate::{BusConfig, BusError};

/// Where POSIX shared memory lives on Linux.
pub(crate) const SHM_DIR: &str = "/dev/shm";

/// Liveness of one iceoryx2 node (one process) of a run.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Liveness {
    /// The process is running.
    Alive,
    /// The process died without cleaning up (e.g. SIGKILL).
    Dead,
    /// Not enough permissions to tell.
    Inaccessible,
    /// Inconsistent bookkeeping (files altered or half-removed).
    Undefined,
}

/// One node found in a run.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct NodeInfo {
    /// Node name, e.g. `qfleet-robot-3` (empty if its details are unreadable).
    pub name: String,
    /// Process id, if known.
    pub pid: Option<i32>,
    /// Executable name, if known.
    pub executable: String,
    /// Whether it is alive.
    pub liveness: Liveness,
    /// Its iceoryx2 node id (`UniqueNodeId::value`, what a sample's header names as its
    /// sender), when its state could be read.
    pub id: Option<u128>,
}

/// Result of [`check_nodes`].
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct NodeReport {
    /// Every node of the run's prefix, as found (before any cleanup).
    pub nodes: Vec<NodeInfo>,
    /// Dead nodes whose stale resources were removed.
    pub cleaned: usize,
    /// Dead nodes whose cleanup failed (permissions, or another process is cleaning them).
    pub cleanup_failed: usize,
}

impl NodeReport {
    /// The nodes whose process is running.
    pub fn alive(&self) -> impl Iterator<Item = &NodeInfo> {
        self.nodes.iter().filter(|n| n.liveness == Liveness::Alive)
    }

    /// The nodes whose process died without cleaning up.
    pub fn dead(&self) -> impl Iterator<Item = &NodeInfo> {
        self.nodes.iter().filter(|n| n.liveness == Liveness::Dead)
    }
}

fn info(state: &NodeState<ipc::Service>) -> NodeInfo {
    let (details, liveness, id) = match state {
        NodeState::Alive(v) => (v.details().clone(), Liveness::Alive, Some(v.id().value())),
        NodeState::Dead(v) => (v.details().clone(), Liveness::Dead, Some(v.id().value())),
        NodeState::Inaccessible(_) => (None, Liveness::Inaccessible, None),
        NodeState::Undefined(_) => (None, Liveness::Undefined, None),
    };
    match details {
        Some(d) => NodeInfo {
            name: d.name().as_str().to_string(),
            pid: Some(d.process_id().value()),
            executable: d.executable().to_string(),
            liveness,
            id,
        },
        None => NodeInfo {
            name: String::new(),
            pid: None,
            executable: String::new(),
            liveness,
            id,
        },
    }
}

/// Lists the nodes; with `clean_dead`, cleans dead ones, retrying failed cleanups a few times:
/// when several dead nodes shared services, cleaning the first leaves the next one's bookkeeping
/// half-removed and iceoryx2 reports an internal error that a second pass resolves.
fn list_and_clean(config: &Config, prefix: &str, clean_dead: bool) -> Result<NodeReport, BusError> {
    let mut report = list_and_clean_once(config, prefix, clean_dead)?;
    for _ in 0..3 {
        if report.cleanup_failed == 0 {
            break;
        }
        let again = list_and_clean_once(config, prefix, true)?;
        report.cleaned += again.cleaned;
        report.cleanup_failed = again.cleanup_failed;
    }
    Ok(report)
}

fn list_and_clean_once(
    config: &Config,
    prefix: &str,
    clean_dead: bool,
) -> Result<NodeReport, BusError> {
    let mut report = NodeReport::default();
    Node::<ipc::Service>::list(config, |state| {
        report.nodes.push(info(&state));
        if clean_dead && let NodeState::Dead(view) = state {
            match view.try_remove_stale_resources() {
                Ok(()) | Err(NodeCleanupFailure::ResourcesAlreadyCleanedUp) => report.cleaned += 1,
                Err(_) => report.cleanup_failed += 1,
            }
        }
        CallbackProgression::Continue
    })
    .map_err(|e| BusError::Liveness {
        prefix: prefix.to_string(),
        detail: format!("cannot list nodes: {e:?}"),
    })?;
    Ok(report)
}

/// Lists the nodes of the run and, if `clean_dead`, removes the stale resources of dead ones
/// (their shared memory, and their ports' slots in every service, so a restarted process can
/// take their place).
pub fn check_nodes(config: &BusConfig, clean_dead: bool) -> Result<NodeReport, BusError> {
    let prefix = config.prefix();
    list_and_clean(&config.iceoryx_config()?, &prefix, clean_dead)
}

/// Result of [`clean_stale`].
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct CleanReport {
    /// The iceoryx2 prefix that was cleaned.
    pub prefix: String,
    /// Nodes still alive; if any, no files were removed.
    pub alive: Vec<NodeInfo>,
    /// Dead nodes cleaned through iceoryx2.
    pub dead_cleaned: usize,
    /// Leftover files removed afterwards.
    pub removed: Vec<PathBuf>,
    /// Empty iceoryx2 node directories removed, of any run ([`remove_empty_node_dirs`]).
    pub empty_node_dirs: usize,
}

/// How old an empty iceoryx2 node directory must be before [`clean_stale`] removes it: far
/// longer than iceoryx2 takes between creating a node's directory and its first file.
pub const EMPTY_NODE_DIR_AGE: std::time::Duration = std::time::Duration::from_secs(10);

/// Removes the directories in `nodes_dir` (iceoryx2's `<root>/nodes/`) that are empty and were
/// last changed at least `min_age` ago; returns how many.
///
/// A process killed (or out of file descriptors) between iceoryx2's creating its node directory
/// and the node's files leaves one behind (seen twice in CI). It is named by node id only, so no
/// prefix tells whose it is; but an empty one holds no node, and the age keeps a node that is
/// being created right now out of reach. A directory that is not empty, or not ours to remove,
/// stays.
pub fn remove_empty_node_dirs(nodes_dir: &Path, min_age: std::time::Duration) -> usize {
    empty_node_dirs(nodes_dir, min_age)
        .into_iter()
        // remove_dir refuses a directory that is not empty (any more)
        .filter(|d| std::fs::remove_dir(d).is_ok())
        .count()
}

/// The directories [`remove_empty_node_dirs`] would remove: empty, and last changed at least
/// `min_age` ago.
pub fn empty_node_dirs(nodes_dir: &Path, min_age: std::time::Duration) -> Vec<PathBuf> {
    let Ok(entries) = std::fs::read_dir(nodes_dir) else {
        return Vec::new();
    };
    let now = std::time::SystemTime::now();
    entries
        .flatten()
        .filter(|e| {
            let Ok(meta) = e.metadata() else {
                return false;
            };
            let old = meta
                .modified()
                .ok()
                .and_then(|t| now.duration_since(t).ok())
                .is_some_and(|age| age >= min_age);
            meta.is_dir()
                && old
                && std::fs::read_dir(e.path()).is_ok_and(|mut d| d.next().is_none())
        })
        .map(|e| e.path())
        .collect()
}

/// [`remove_empty_node_dirs`] in iceoryx2's own node directory, [`EMPTY_NODE_DIR_AGE`] old.
pub fn sweep_empty_node_dirs() -> usize {
    remove_empty_node_dirs(&iceoryx_root().join("nodes"), EMPTY_NODE_DIR_AGE)
}

/// What [`sweep_empty_node_dirs`] would remove now (for `qfleet clean --dry-run`).
pub fn stale_empty_node_dirs() -> Vec<PathBuf> {
    empty_node_dirs(&iceoryx_root().join("nodes"), EMPTY_NODE_DIR_AGE)
}

/// Cleans up everything a run with iceoryx2 prefix `prefix` (e.g. `qfleet.<run-id>.`) left
/// behind: first dead nodes through iceoryx2, then — only if no node of the prefix is alive —
/// every remaining file of the prefix in `/dev/shm` and under iceoryx2's root path (a clean exit
/// still leaves a small per-prefix management file). For `qfleet clean`.
pub fn clean_stale(prefix: &str) -> Result<CleanReport, BusError> {
    let config = iceoryx_config_for_prefix(prefix)?;
    // a segment whose creator was killed before it finished has no read permission yet, and
    // iceoryx2's dead-node cleanup waits for it to get one without end (a `qfleet clean`
    // hung in CI on a zero-length `.connection` of mode 0200): with nobody of the run alive,
    // nobody will finish it, so it goes first
    if list_and_clean(&config, prefix, false)?
        .alive()
        .next()
        .is_none()
    {
        remove_unfinished_segments(Path::new(SHM_DIR), prefix);
    }
    let nodes = list_and_clean(&config, prefix, true)?;
    let alive: Vec<NodeInfo> = nodes.alive().cloned().collect();
    let mut report = CleanReport {
        prefix: prefix.to_string(),
        dead_cleaned: nodes.cleaned,
        alive,
        removed: Vec::new(),
        empty_node_dirs: sweep_empty_node_dirs(),
    };
    if !report.alive.is_empty() {
        return Ok(report);
    }
    for path in leftover_files(prefix) {
        let result = if path.is_dir() {
            std::fs::remove_dir_all(&path)
        } else {
            std::fs::remove_file(&path)
        };
        match result {
            Ok(()) => {
                remove_if_empty_node_dir(&path);
                report.removed.push(path);
            }
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => {}
            Err(source) => {
                return Err(BusError::Cleanup {
                    path: path.display().to_string(),
                    source,
                });
            }
        }
    }
    Ok(report)
}

/// Removes the files of `prefix` in `dir` that their owner cannot read: shared memory that
/// iceoryx2 creates write-only and opens to reading once initialized, left half made by a
/// killed process. Returns how many. Only for a run with no live process.
fn remove_unfinished_segments(dir: &Path, prefix: &str) -> usize {
    use std::os::unix::fs::PermissionsExt;
    let mut found = Vec::new();
    collect(dir, prefix, false, &mut found);
    found
        .into_iter()
        .filter(|p| {
            std::fs::symlink_metadata(p)
                .is_ok_and(|m| m.is_file() && m.permissions().mode() & 0o400 == 0)
        })
        .filter(|p| std::fs::remove_file(p).is_ok())
        .count()
}

/// Removes the per-node directory (`<root>/nodes/<node-id>/`) that held `removed_file`, if it
/// is now empty; it is named by node id only, so it never matches the prefix itself.
fn remove_if_empty_node_dir(removed_file: &Path) {
    let nodes = iceoryx_root().join("nodes");
    if let Some(dir) = removed_file.parent()
        && dir.parent() == Some(nodes.as_path())
    {
        // fails harmlessly if the directory still holds files of another run
        let _ = std::fs::remove_dir(dir);
    }
}

/// [`clean_stale`] for the run described by `config`.
pub fn clean_run(config: &BusConfig) -> Result<CleanReport, BusError> {
    config.validate()?;
    clean_stale(&config.prefix())
}

/// iceoryx2's root path (`/tmp/iceoryx2/` unless changed at build time).
pub fn iceoryx_root() -> PathBuf {
    PathBuf::from(Config::default().global.root_path().to_string())
}

/// Every file or directory whose name starts with `prefix`, in `/dev/shm` and (recursively)
/// under iceoryx2's root path. Empty once a run is fully cleaned up.
pub fn leftover_files(prefix: &str) -> Vec<PathBuf> {
    let mut found = Vec::new();
    collect(Path::new(SHM_DIR), prefix, false, &mut found);
    collect(&iceoryx_root(), prefix, true, &mut found);
    found.sort();
    found
}

fn collect(dir: &Path, prefix: &str, recurse: bool, found: &mut Vec<PathBuf>) {
    let Ok(entries) = std::fs::read_dir(dir) else {
        return;
    };
    for entry in entries.flatten() {
        let path = entry.path();
        if entry.file_name().to_string_lossy().starts_with(prefix) {
            found.push(path);
        } else if recurse && entry.file_type().is_ok_and(|t| t.is_dir()) {
            collect(&path, prefix, true, found);
        }
    }
}

/// The iceoryx2 prefixes of qfleet runs that have files in `/dev/shm` or iceoryx2's root path,
/// e.g. `qfleet.run7.`, for `qfleet clean --all`.
pub fn find_run_prefixes() -> Vec<String> {
    let mut found = Vec::new();
    collect(Path::new(SHM_DIR), "qfleet.", false, &mut found);
    collect(&iceoryx_root(), "qfleet.", true, &mut found);
    let mut prefixes: Vec<String> = found
        .iter()
        .filter_map(|p| p.file_name()?.to_str().map(str::to_string))
        .filter_map(|name| {
            let rest = name.strip_prefix("qfleet.")?;
            let (run_id, _) = rest.split_once('.')?;
            Some(format!("qfleet.{run_id}."))
        })
        .collect();
    prefixes.sort();
    prefixes.dedup();
    prefixes
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::time::Duration;

    #[test]
    fn only_unreadable_files_of_the_prefix_count_as_unfinished() {
        use std::os::unix::fs::PermissionsExt;
        let dir = std::env::temp_dir().join(format!("qfleet-unfinished-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let file = |name: &str, mode: u32| {
            let p = dir.join(name);
            std::fs::write(&p, b"").unwrap();
            std::fs::set_permissions(&p, std::fs::Permissions::from_mode(mode)).unwrap();
            p
        };
        let half = file("qfleet.r.a.connection", 0o200);
        let done = file("qfleet.r.b.connection", 0o600);
        let other = file("qfleet.s.c.connection", 0o200);
        assert_eq!(remove_unfinished_segments(&dir, "qfleet.r."), 1);
        assert!(!half.exists() && done.exists() && other.exists());
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[test]
    fn only_empty_node_directories_old_enough_are_removed() {
        let root = std::env::temp_dir().join(format!("qfleet-nodes-test-{}", std::process::id()));
        let (empty, full) = (root.join("111"), root.join("222"));
        std::fs::create_dir_all(&empty).unwrap();
        std::fs::create_dir_all(&full).unwrap();
        std::fs::write(full.join("qfleet.x.node_monitor"), b"").unwrap();
        // too young: a node may be being created in it right now
        assert_eq!(remove_empty_node_dirs(&root, Duration::from_secs(3600)), 0);
        assert!(empty.exists());
        assert!(empty_node_dirs(&root, Duration::from_secs(3600)).is_empty());
        // old enough: the empty one goes, the one holding a node's file stays; a dry run names
        // exactly that one and removes nothing
        assert_eq!(
            empty_node_dirs(&root, Duration::ZERO),
            std::slice::from_ref(&empty)
        );
        assert!(empty.exists());
        assert_eq!(remove_empty_node_dirs(&root, Duration::ZERO), 1);
        assert!(!empty.exists() && full.exists());
        // a missing directory is nothing to do, not an error
        assert_eq!(
            remove_empty_node_dirs(&root.join("absent"), Duration::ZERO),
            0
        );
        std::fs::remove_dir_all(&root).unwrap();
    }
}
