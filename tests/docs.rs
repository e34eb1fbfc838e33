//! The documentation against the code: the README stays a front page,
//! the guide's chapters and links resolve, the pipeline.toml reference
//! names exactly the keys the parser accepts, and every command the docs
//! show is a real command that a test (this one, or the one named) runs.
//!
//! Documents checked: README.md, CONTRIBUTING.md and every page of the
//! guide in docs/guide/src/.

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};
use std::process::Command;

use magcomp::config::{accepted_keys, Pipeline, MAP_TABLES};

/// The README is the front page; the guide holds the rest.
const README_MOST_LINES: usize = 200;

/// Commands shown in the docs that this test does not run, with what runs
/// them: `.ci/run` runs the README's pipeline command on the sample
/// flights; `tests/<name>.rs` runs the subcommand as the docs show it.
const RUN_ELSEWHERE: &[(&str, &str)] = &[("cargo run --release -- run pipeline.toml", ".ci/run")];

fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

fn guide() -> PathBuf {
    root().join("docs/guide/src")
}

fn read(path: &Path) -> String {
    std::fs::read_to_string(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

/// README.md, CONTRIBUTING.md and every page of the guide.
fn documents() -> Vec<PathBuf> {
    let mut pages: Vec<PathBuf> = std::fs::read_dir(guide())
        .unwrap()
        .map(|entry| entry.unwrap().path())
        .filter(|path| path.extension().is_some_and(|e| e == "md"))
        .collect();
    pages.sort();
    [root().join("README.md"), root().join("CONTRIBUTING.md")]
        .into_iter()
        .chain(pages)
        .collect()
}

fn shown(path: &Path) -> String {
    path.strip_prefix(root()).unwrap_or(path).display().to_string()
}

/// A fenced block: its info string (`sh`, `toml`, …) and its lines.
struct Block {
    info: String,
    lines: Vec<String>,
}

/// The fenced blocks of `text`, and the prose lines outside them.
fn split_blocks(text: &str) -> (Vec<Block>, Vec<String>) {
    let (mut blocks, mut prose) = (Vec::new(), Vec::new());
    let mut open: Option<Block> = None;
    for line in text.lines() {
        let fence = line.trim_start().strip_prefix("```");
        match (fence, open.take()) {
            (Some(info), None) => {
                open = Some(Block {
                    info: info.trim().to_string(),
                    lines: Vec::new(),
                })
            }
            (Some(_), Some(block)) => blocks.push(block),
            (None, Some(mut block)) => {
                block.lines.push(line.to_string());
                open = Some(block);
            }
            (None, None) => prose.push(line.to_string()),
        }
    }
    assert!(open.is_none(), "a fenced block is not closed");
    (blocks, prose)
}

/// The inline code spans of `prose` (joined across line breaks, as
/// markdown joins them).
fn code_spans(prose: &str) -> Vec<String> {
    let joined = prose.replace('\n', " ");
    joined.split('`').skip(1).step_by(2).map(String::from).collect()
}

/// `prose` without its inline code spans.
fn without_code(prose: &str) -> String {
    prose.split('`').step_by(2).collect::<Vec<_>>().join("")
}

/// The targets of the markdown links `[text](target)` in `prose`.
fn link_targets(prose: &str) -> Vec<String> {
    let text = without_code(prose);
    let mut targets = Vec::new();
    let mut rest = text.as_str();
    while let Some(at) = rest.find("](") {
        let after = &rest[at + 2..];
        let end = after.find(')').unwrap_or(after.len());
        targets.push(after[..end].trim().to_string());
        rest = &after[end..];
    }
    targets
}

/// The anchor a heading gets (mdBook's and GitHub's rule): lower case,
/// spaces to `-`, everything but letters, digits, `-` and `_` dropped.
fn anchor(heading: &str) -> String {
    heading
        .trim()
        .to_lowercase()
        .chars()
        .filter_map(|c| match c {
            ' ' => Some('-'),
            c if c.is_alphanumeric() || c == '-' || c == '_' => Some(c),
            _ => None,
        })
        .collect()
}

fn anchors(text: &str) -> BTreeSet<String> {
    let (_, prose) = split_blocks(text);
    prose
        .iter()
        .filter_map(|line| line.strip_prefix('#'))
        .map(|heading| anchor(heading.trim_start_matches('#')))
        .collect()
}

#[test]
fn the_readme_is_a_front_page() {
    let lines = read(&root().join("README.md")).lines().count();
    assert!(
        lines <= README_MOST_LINES,
        "README.md has {lines} lines, more than {README_MOST_LINES}: move the detail into a chapter of docs/guide"
    );
}

#[test]
fn the_summary_lists_every_chapter_and_only_chapters_that_exist() {
    let summary = read(&guide().join("SUMMARY.md"));
    let listed: BTreeSet<String> = link_targets(&summary).into_iter().collect();
    for chapter in &listed {
        assert!(
            guide().join(chapter).is_file(),
            "SUMMARY.md lists {chapter}, which is not in docs/guide/src"
        );
    }
    for page in documents().iter().filter(|p| p.starts_with(guide())) {
        let name = page.file_name().unwrap().to_string_lossy().into_owned();
        assert!(
            name == "SUMMARY.md" || listed.contains(&name),
            "docs/guide/src/{name} is not listed in SUMMARY.md, so the book leaves it out"
        );
    }
}

#[test]
fn every_relative_link_and_file_named_in_the_docs_exists() {
    let mut broken = Vec::new();
    for document in documents() {
        let text = read(&document);
        let (_, prose) = split_blocks(&text);
        let prose = prose.join("\n");
        let folder = document.parent().unwrap();
        for target in link_targets(&prose) {
            if target.contains("://") || target.starts_with("mailto:") {
                continue;
            }
            let (file, fragment) = target.split_once('#').unwrap_or((&target, ""));
            let path = if file.is_empty() {
                document.clone()
            } else {
                folder.join(file)
            };
            if !path.exists() {
                broken.push(format!("{}: link to {target}: no such file", shown(&document)));
            } else if !fragment.is_empty()
                && path.extension().is_some_and(|e| e == "md")
                && !anchors(&read(&path)).contains(fragment)
            {
                broken.push(format!("{}: link to {target}: no such heading", shown(&document)));
            }
        }
        // Repository files named in code spans (`src/calibration/detect.rs`,
        // `tests/vector.rs`, …), relative to the repository root.
        let folders = [
            "src/",
            "tests/",
            "benches/",
            "fuzz/",
            "examples/",
            "sample_flights/",
            "data/",
            "docs/",
            ".ci/",
        ];
        for span in code_spans(&prose) {
            let named = span.split_whitespace().next().unwrap_or("");
            let is_path = folders.iter().any(|f| named.starts_with(f)) && !named.contains(['<', '*', '|']);
            if is_path && !root().join(named.trim_end_matches([',', ';', ':'])).exists() {
                broken.push(format!("{}: `{named}` is not in the repository", shown(&document)));
            }
        }
    }
    assert!(broken.is_empty(), "broken references:\n{}", broken.join("\n"));
}

// ---------------------------------------------------------------------------
// The pipeline.toml reference against the parser.

fn reference_page() -> String {
    read(&guide().join("pipeline-toml.md"))
}

/// The reference page's examples, in page order, as one pipeline.toml.
fn reference_examples() -> String {
    let (blocks, _) = split_blocks(&reference_page());
    let examples: Vec<String> = blocks
        .into_iter()
        .filter(|b| b.info == "toml")
        .map(|b| b.lines.join("\n"))
        .collect();
    assert!(examples.len() >= 10, "the reference page has an example per section");
    examples.join("\n\n") + "\n"
}

/// Every key path of `value` below `prefix`, tables and arrays of tables
/// entered (`fit`, `fit.terms`, `flight.windows.t_start`, …).
fn key_paths(value: &toml::Value, prefix: &str, paths: &mut BTreeSet<String>) {
    let tables: Vec<&toml::Table> = match value {
        toml::Value::Table(table) => vec![table],
        toml::Value::Array(items) => items.iter().filter_map(toml::Value::as_table).collect(),
        _ => Vec::new(),
    };
    for table in tables {
        for (key, inner) in table {
            let path = if prefix.is_empty() {
                key.clone()
            } else {
                format!("{prefix}.{key}")
            };
            paths.insert(path.clone());
            key_paths(inner, &path, paths);
        }
    }
}

/// Every key path the parser accepts (`[sensor_positions]` takes sensor
/// names, so none is listed below it).
fn accepted_paths() -> BTreeSet<String> {
    let mut paths = BTreeSet::new();
    for (section, keys) in accepted_keys() {
        for key in keys {
            paths.insert(if section.is_empty() {
                key.to_string()
            } else {
                format!("{section}.{key}")
            });
        }
    }
    paths
}

#[test]
fn the_key_listing_covers_every_section_of_the_file() {
    let keys = accepted_keys();
    let sections: BTreeSet<&str> = keys.iter().map(|(section, _)| *section).collect();
    let (_, top) = keys.iter().find(|(section, _)| section.is_empty()).unwrap();
    for section in *top {
        assert!(
            sections.contains(section),
            "accepted_keys() lists no keys for [{section}]"
        );
    }
    // Read from the serde derives: a few keys that must be there.
    let paths = accepted_paths();
    for known in [
        "fit.solver",
        "flight.windows_file",
        "quality.transfer.warning_factor",
        "columns.vector.prefix",
        "topic",
    ] {
        assert!(paths.contains(known), "accepted_keys() lacks {known}: {paths:?}");
    }
}

#[test]
fn the_reference_documents_every_key_the_parser_accepts_and_no_other() {
    let examples: toml::Value = toml::from_str(&reference_examples()).expect("the reference's examples are TOML");
    let mut documented = BTreeSet::new();
    key_paths(&examples, "", &mut documented);
    documented.retain(|path| !MAP_TABLES.iter().any(|table| path.starts_with(&format!("{table}."))));
    let accepted = accepted_paths();
    let undocumented: Vec<&String> = accepted.difference(&documented).collect();
    let unknown: Vec<&String> = documented.difference(&accepted).collect();
    assert!(
        undocumented.is_empty(),
        "keys pipeline.toml accepts that no example of docs/guide/src/pipeline-toml.md shows: {undocumented:?}"
    );
    assert!(
        unknown.is_empty(),
        "keys docs/guide/src/pipeline-toml.md shows that pipeline.toml rejects: {unknown:?}"
    );

    // The tables: every key in a row's first cell is accepted in a section
    // its heading names (or one below it), and every key of those
    // sections has a row (a key holding a table of its own is documented
    // by its keys' rows; a window's keys are in the `windows` row's text).
    let mut section: Vec<String> = Vec::new();
    let mut rows: BTreeSet<String> = BTreeSet::new();
    let (_, prose) = split_blocks(&reference_page());
    for line in prose {
        if let Some(heading) = line.strip_prefix("## ") {
            section = code_spans(heading)
                .iter()
                .map(|s| s.trim_matches(['[', ']']).to_string())
                .collect();
            continue;
        }
        let Some(first_cell) = line.strip_prefix('|').and_then(|l| l.split('|').next()) else {
            continue;
        };
        for key in code_spans(first_cell) {
            let path = section.iter().find_map(|s| {
                let direct = format!("{s}.{key}");
                match accepted.contains(&direct) {
                    true => Some(direct),
                    false => (accepted.iter())
                        .find(|p| p.starts_with(&format!("{s}.")) && p.ends_with(&format!(".{key}")))
                        .cloned(),
                }
            });
            match path {
                Some(path) => {
                    rows.insert(path);
                }
                None => panic!(
                    "docs/guide/src/pipeline-toml.md has a row for `{key}` under {section:?}, which pipeline.toml rejects there"
                ),
            }
        }
    }
    let holds_a_table = |path: &String| accepted.iter().any(|p| p.starts_with(&format!("{path}.")));
    let without_row: Vec<&String> = (accepted.iter())
        .filter(|p| p.contains('.') && !p.starts_with("flight.windows."))
        .filter(|p| !rows.contains(*p) && !holds_a_table(p))
        .collect();
    assert!(
        without_row.is_empty(),
        "keys without a row in the tables of docs/guide/src/pipeline-toml.md: {without_row:?}"
    );
}

/// A folder holding the files the reference's examples name, and the
/// examples as its pipeline.toml.
fn reference_folder() -> tempfile::TempDir {
    let folder = tempfile::tempdir().unwrap();
    let at = |name: &str| {
        let path = folder.path().join(name);
        std::fs::create_dir_all(path.parent().unwrap()).unwrap();
        path
    };
    let flight = root().join("sample_flights/clean.csv");
    for name in [
        "flights/f017.csv",
        "archive/f018.csv",
        "archive/f019.csv",
        "flights/f020.csv",
        "more/f020.csv",
    ] {
        std::fs::copy(&flight, at(name)).unwrap();
    }
    std::fs::copy(root().join("sample_flights/clean.windows.json"), at("f018_detect.json")).unwrap();
    std::fs::write(at("flights.csv"), "input\nmore/f020.csv\n").unwrap();
    std::fs::write(at("pipeline.toml"), reference_examples()).unwrap();
    folder
}

#[test]
fn the_reference_examples_load_and_a_key_the_parser_does_not_know_is_refused() {
    let folder = reference_folder();
    let path = folder.path().join("pipeline.toml");
    let pipeline = Pipeline::load(&path).unwrap_or_else(|e| panic!("the reference's examples do not load: {e}"));
    assert_eq!(pipeline.flights.len(), 5, "four [[flight]] tables and a manifest row");

    // A made-up key in each table is refused, and the error names it.
    let examples: toml::Table = toml::from_str(&reference_examples()).unwrap();
    for (section, _) in accepted_keys() {
        if MAP_TABLES.contains(&section) {
            continue;
        }
        let mut changed = examples.clone();
        let mut table = &mut changed;
        for part in section.split('.').filter(|p| !p.is_empty()) {
            let inner = table
                .get_mut(part)
                .unwrap_or_else(|| panic!("the examples have no [{section}]"));
            table = match inner {
                toml::Value::Table(t) => t,
                toml::Value::Array(items) => items[0].as_table_mut().unwrap(),
                other => panic!("[{section}] is {other:?}"),
            };
        }
        table.insert("made_up_key".into(), toml::Value::Integer(1));
        std::fs::write(&path, toml::to_string(&changed).unwrap()).unwrap();
        match Pipeline::load(&path) {
            Ok(_) => panic!("a made-up key in [{section}] was accepted"),
            Err(e) => assert!(
                e.to_string().contains("made_up_key"),
                "a made-up key in [{section}]: the error does not name it: {e}"
            ),
        }
    }
}

// ---------------------------------------------------------------------------
// Commands.

/// One command shown in a document, as written (continuation lines
/// joined, comment dropped).
struct Shown {
    document: PathBuf,
    text: String,
    in_block: bool,
}

fn shell_block(info: &str) -> bool {
    matches!(info, "sh" | "bash" | "console" | "shell")
}

fn commands() -> Vec<Shown> {
    let mut shown = Vec::new();
    for document in documents() {
        let (blocks, prose) = split_blocks(&read(&document));
        for block in blocks.iter().filter(|b| shell_block(&b.info)) {
            let mut pending = String::new();
            for line in &block.lines {
                let line = line.trim().trim_start_matches("$ ");
                let line = line.split(" #").next().unwrap().trim();
                match line.strip_suffix('\\') {
                    Some(start) => pending += &format!("{} ", start.trim()),
                    None if line.is_empty() => {}
                    None => {
                        let text = std::mem::take(&mut pending) + line;
                        shown.push(Shown {
                            document: document.clone(),
                            text,
                            in_block: true,
                        });
                    }
                }
            }
        }
        for span in code_spans(&prose.join("\n")) {
            if span.starts_with("magcomp ") {
                shown.push(Shown {
                    document: document.clone(),
                    text: span.split_whitespace().collect::<Vec<_>>().join(" "),
                    in_block: false,
                });
            }
        }
    }
    shown
}

/// The arguments after `magcomp` of a magcomp command, or None for
/// another program.
fn magcomp_arguments(text: &str) -> Option<Vec<String>> {
    let rest = text
        .strip_prefix("magcomp ")
        .or_else(|| text.strip_prefix("cargo run --release -- "))?;
    Some(rest.split_whitespace().map(String::from).collect())
}

fn help(arguments: &[&str]) -> String {
    let output = Command::new(env!("CARGO_BIN_EXE_magcomp"))
        .args(arguments)
        .arg("--help")
        .output()
        .unwrap();
    assert!(output.status.success(), "magcomp {arguments:?} --help failed");
    String::from_utf8(output.stdout).unwrap()
}

/// The subcommands `magcomp --help` lists, each with the flags its own
/// `--help` lists.
fn subcommands() -> BTreeMap<String, BTreeSet<String>> {
    let top = help(&[]);
    let listed = top
        .split("Commands:")
        .nth(1)
        .expect("magcomp --help lists its commands");
    let listed = listed.split("\n\n").next().unwrap();
    listed
        .lines()
        .filter(|line| line.starts_with("  ") && !line.starts_with("   "))
        .filter_map(|line| line.split_whitespace().next())
        .filter(|name| *name != "help")
        .map(|name| {
            let flags = help(&[name])
                .split(|c: char| c.is_whitespace() || c == ',' || c == '[' || c == ']' || c == '=')
                .filter(|word| word.starts_with("--"))
                .map(|word| word.trim_end_matches(['.', ')', ':']).to_string())
                .collect();
            (name.to_string(), flags)
        })
        .collect()
}

#[test]
fn every_magcomp_command_in_the_docs_is_a_real_subcommand_with_real_flags() {
    let known = subcommands();
    assert!(
        known.contains_key("compensate") && known["compensate"].contains("--out"),
        "{known:?}"
    );
    let mut wrong = Vec::new();
    let mut checked = 0;
    for command in commands() {
        let Some(arguments) = magcomp_arguments(&command.text) else {
            continue;
        };
        checked += 1;
        let subcommand = &arguments[0];
        let Some(flags) = known.get(subcommand) else {
            wrong.push(format!(
                "{}: `{}`: magcomp has no subcommand {subcommand}",
                shown(&command.document),
                command.text
            ));
            continue;
        };
        for argument in &arguments[1..] {
            let flag = argument.trim_matches(['[', ']']).split('=').next().unwrap();
            if flag.starts_with("--") && !flags.contains(flag) {
                wrong.push(format!(
                    "{}: `{}`: magcomp {subcommand} has no {flag}",
                    shown(&command.document),
                    command.text
                ));
            }
        }
    }
    assert!(checked >= 20, "only {checked} magcomp commands found in the docs");
    assert!(wrong.is_empty(), "{}", wrong.join("\n"));
}

#[test]
fn the_ci_runs_the_readme_commands_and_the_benches_named_exist() {
    let ci = read(&root().join(".ci/run"));
    let ci_lines: BTreeSet<&str> = ci.lines().map(str::trim).collect();
    let readme: Vec<Shown> = commands()
        .into_iter()
        .filter(|c| c.in_block && c.document.ends_with("README.md"))
        .collect();
    let test_command = readme
        .iter()
        .find(|c| c.text.starts_with("cargo test"))
        .expect("the README shows the test command");
    assert!(
        ci_lines.contains(test_command.text.as_str()),
        ".ci/run does not run the README's test command `{}`",
        test_command.text
    );
    for (command, runner) in RUN_ELSEWHERE {
        let runner_text = read(&root().join(runner));
        assert!(
            runner_text.lines().any(|line| line.trim() == *command),
            "{runner} does not run `{command}`"
        );
    }
    let manifest = read(&root().join("Cargo.toml"));
    for command in commands().iter().filter(|c| c.in_block) {
        if let Some(bench) = command.text.strip_prefix("cargo bench --bench ") {
            let name = bench.split_whitespace().next().unwrap();
            assert!(
                manifest.contains(&format!("[[bench]]\nname = \"{name}\"")),
                "{}: `{}`: Cargo.toml has no bench {name}",
                shown(&command.document),
                command.text
            );
        }
    }
}

/// Runs `arguments` in `folder` and fails with its output unless it
/// succeeds: exit 0, or 3 where a channel's verdict is FAIL (the outputs
/// written, CONTRACT §2).
fn run_in(folder: &Path, arguments: &[String], command: &Shown) {
    let output = Command::new(env!("CARGO_BIN_EXE_magcomp"))
        .current_dir(folder)
        .args(arguments)
        .output()
        .unwrap();
    let failed_channel = String::from_utf8_lossy(&output.stdout).contains(": FAIL");
    assert!(
        output.status.success() || (failed_channel && output.status.code() == Some(3)),
        "{}: `{}` failed:\n{}{}",
        shown(&command.document),
        command.text,
        String::from_utf8_lossy(&output.stdout),
        String::from_utf8_lossy(&output.stderr)
    );
    if let Some(at) = arguments.iter().position(|a| a == "--out") {
        let out = folder.join(&arguments[at + 1]);
        assert!(out.exists(), "`{}` wrote no {}", command.text, out.display());
    }
}

/// A folder for one document's commands: the placeholders they use
/// (`FLIGHT.csv`, `FLIGHT`, `cal.csv`, `survey.csv`) are the clean sample flight,
/// `PLAN.toml` a one-flight plan, and `pipeline.toml` the document's own
/// pipeline.toml example (the README's) or the repository's.
fn command_folder(document: &Path) -> tempfile::TempDir {
    let folder = tempfile::tempdir().unwrap();
    let flight = root().join("sample_flights/clean.csv");
    for name in ["FLIGHT.csv", "FLIGHT", "cal.csv", "survey.csv"] {
        std::fs::copy(&flight, folder.path().join(name)).unwrap();
    }
    std::fs::write(folder.path().join("PLAN.toml"), "[plan]\nrealisations = 2\n").unwrap();
    let (blocks, _) = split_blocks(&read(document));
    let own = blocks
        .iter()
        .find(|b| b.info == "toml" && b.lines.iter().any(|l| l.starts_with("[[flight]]")));
    match own {
        Some(block) if document.ends_with("README.md") => {
            std::fs::write(folder.path().join("pipeline.toml"), block.lines.join("\n")).unwrap()
        }
        _ => {
            std::fs::copy(root().join("pipeline.toml"), folder.path().join("pipeline.toml")).unwrap();
        }
    }
    folder
}

/// Every magcomp command in a shell block is run, in the order shown and
/// one folder per document, on the clean sample flight (optional
/// arguments in brackets given, `...` dropped), unless
/// [`RUN_ELSEWHERE`] names what runs it.
#[test]
fn every_magcomp_command_shown_in_a_block_runs() {
    let mut by_document: BTreeMap<PathBuf, Vec<Shown>> = BTreeMap::new();
    for command in commands().into_iter().filter(|c| c.in_block) {
        if magcomp_arguments(&command.text).is_some() && !RUN_ELSEWHERE.iter().any(|(c, _)| *c == command.text) {
            by_document.entry(command.document.clone()).or_default().push(command);
        }
    }
    assert!(by_document.len() >= 3, "commands found in {:?}", by_document.keys());
    for (document, shown_commands) in by_document {
        let folder = command_folder(&document);
        for command in &shown_commands {
            let arguments: Vec<String> = magcomp_arguments(&command.text)
                .unwrap()
                .into_iter()
                .map(|a| a.trim_matches(['[', ']']).to_string())
                .filter(|a| a != "..." && !a.is_empty())
                .collect();
            run_in(folder.path(), &arguments, command);
        }
    }
}
