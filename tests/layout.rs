//! The README's layout table is the crate graph `cargo metadata` reports: one row per workspace
//! package, and each row's "depends on" column names exactly that package's workspace
//! dependencies (normal and dev). A dependency added or removed without the README following
//! fails here, as does a crate outside the two processes that links one of them.

use serde_json::Value;
use std::collections::{BTreeMap, BTreeSet};
use std::process::Command;

/// Workspace packages: name → (directory relative to the workspace root, workspace deps).
fn workspace_graph() -> BTreeMap<String, (String, BTreeSet<String>)> {
    let root = env!("CARGO_MANIFEST_DIR");
    let cargo = std::env::var("CARGO").unwrap_or_else(|_| "cargo".into());
    let out = Command::new(cargo)
        .current_dir(root)
        .args([
            "metadata",
            "--format-version",
            "1",
            "--no-deps",
            "--offline",
        ])
        .output()
        .expect("run cargo metadata");
    assert!(
        out.status.success(),
        "cargo metadata: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    let meta: Value = serde_json::from_slice(&out.stdout).expect("cargo metadata JSON");
    let packages = meta["packages"].as_array().expect("packages");
    let names: BTreeSet<String> = packages
        .iter()
        .map(|p| p["name"].as_str().expect("name").to_string())
        .collect();
    packages
        .iter()
        .map(|p| {
            let manifest = std::path::Path::new(p["manifest_path"].as_str().expect("path"));
            let dir = manifest
                .parent()
                .expect("package dir")
                .strip_prefix(root)
                .expect("package inside the workspace")
                .to_string_lossy()
                .into_owned();
            let deps = p["dependencies"]
                .as_array()
                .expect("dependencies")
                .iter()
                .map(|d| d["name"].as_str().expect("dep name").to_string())
                .filter(|d| names.contains(d))
                .collect();
            (p["name"].as_str().unwrap().to_string(), (dir, deps))
        })
        .collect()
}

/// The README's "## Layout" table: (first cell, third cell) of each body row.
fn readme_rows() -> Vec<(String, String)> {
    let readme = std::fs::read_to_string(concat!(env!("CARGO_MANIFEST_DIR"), "/README.md"))
        .expect("README.md");
    let section = readme
        .split("\n## Layout\n")
        .nth(1)
        .expect("a '## Layout' section")
        .split("\n## ")
        .next()
        .unwrap();
    section
        .lines()
        .filter(|l| l.starts_with('|') && !l.starts_with("|---") && !l.starts_with("| crate"))
        .map(|l| {
            let cells: Vec<&str> = l.trim_matches('|').split(" | ").collect();
            assert_eq!(cells.len(), 3, "a layout row has three cells: {l}");
            (cells[0].trim().to_string(), cells[2].trim().to_string())
        })
        .collect()
}

/// The workspace package names a cell mentions (as whole words: `bus` is not in `bus-schema`).
fn names_in(cell: &str, names: &BTreeSet<String>) -> BTreeSet<String> {
    cell.split(|c: char| !(c.is_ascii_alphanumeric() || c == '-' || c == '_'))
        .filter(|w| names.contains(*w))
        .map(str::to_string)
        .collect()
}

#[test]
fn the_readme_layout_table_is_the_crate_graph_of_cargo_metadata() {
    let graph = workspace_graph();
    let names: BTreeSet<String> = graph.keys().cloned().collect();
    let rows = readme_rows();
    for (name, (dir, deps)) in &graph {
        // a row names its package by directory (`planner/`), or as the root package
        let row = rows.iter().find(|(first, _)| {
            if dir.is_empty() {
                first.contains("root package")
            } else {
                first.contains(&format!("`{dir}/`"))
            }
        });
        let Some((_, depends)) = row else {
            panic!("README layout table has no row for {name} ({dir}/)");
        };
        assert_eq!(
            &names_in(depends, &names),
            deps,
            "README layout row of {name}: 'depends on' must name exactly its workspace deps"
        );
    }
    assert_eq!(
        rows.len(),
        graph.len(),
        "one README layout row per workspace package: {rows:?}"
    );
}

#[test]
fn names_in_a_cell_are_whole_words() {
    let names: BTreeSet<String> = ["bus", "bus-schema", "report"]
        .into_iter()
        .map(String::from)
        .collect();
    let got = names_in("bus-schema, report (through `x`)", &names);
    assert_eq!(
        got,
        ["bus-schema", "report"]
            .into_iter()
            .map(String::from)
            .collect()
    );
}

/// The two processes are leaves of the crate graph: the launcher, `qfleet`, `fleetbench`, the
/// bridge and the tests reach them only through their command lines (the `contract` crate) and
/// their results (`report`), never by linking them.
#[test]
fn no_crate_outside_the_processes_depends_on_a_process_crate() {
    let processes = ["coordinator", "robot-agent"];
    for (name, (_, deps)) in workspace_graph() {
        for p in processes {
            assert!(
                !deps.contains(p),
                "{name} depends on the process crate {p}: build its command line with the \
                 contract crate and read its results with report instead"
            );
        }
    }
}
