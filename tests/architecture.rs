//! The module graph of `src/`: which top-level modules use which, and the
//! import cycles among them.
//!
//! A module is a file `src/<name>.rs` or a folder `src/<name>/`; an edge
//! `a → b` is any `crate::b` path in `a`'s code outside its unit tests
//! (comments are skipped, so a documentation link is not an edge). A
//! cycle is a strongly connected component of more than one module: each
//! of its modules reaches every other one, so none can be read, tested or
//! moved alone.
//!
//! The cycles the code has are listed in [`KNOWN_CYCLES`], a ratchet for
//! the redesign that removes them: a new cycle fails the test, and so does
//! a listed one that has gone (then it is struck from the list, so it
//! cannot come back).

use std::collections::{BTreeMap, BTreeSet};
use std::path::Path;

/// The import cycles of `src/` today, each as its modules in name order:
/// none since the model, format and sink redesign. A cycle that comes back
/// fails the test.
const KNOWN_CYCLES: &[&[&str]] = &[];

/// `text` without `//` comments (doc comments included) and without its
/// unit-test module.
fn code_of(text: &str) -> String {
    let test_module = ["#[cfg(test)]\nmod tests", "#[cfg(test)]\npub(crate) mod tests"]
        .iter()
        .filter_map(|start| text.find(start))
        .min();
    let text = match test_module {
        Some(at) => &text[..at],
        None => text,
    };
    text.lines()
        .map(|line| match line.find("//") {
            // A `//` inside a string literal ("https://…") keeps its line.
            Some(at) if line[..at].matches('"').count() % 2 == 0 => &line[..at],
            _ => line,
        })
        .collect::<Vec<_>>()
        .join("\n")
}

/// The top-level modules named by `crate::` paths in `code`, grouped
/// imports (`crate::{a::X, b}`) included.
fn modules_used(code: &str) -> BTreeSet<String> {
    let identifier = |s: &str| -> String {
        s.chars()
            .take_while(|c| c.is_ascii_alphanumeric() || *c == '_')
            .collect()
    };
    let mut used = BTreeSet::new();
    for (at, _) in code.match_indices("crate::") {
        let rest = &code[at + "crate::".len()..];
        if !rest.starts_with('{') {
            used.insert(identifier(rest));
            continue;
        }
        let mut depth = 0;
        let mut expect_item = false;
        for (k, c) in rest.char_indices() {
            match c {
                '{' => {
                    depth += 1;
                    expect_item = depth == 1;
                }
                '}' => {
                    depth -= 1;
                    if depth == 0 {
                        break;
                    }
                }
                ',' if depth == 1 => expect_item = true,
                c if expect_item && (c.is_ascii_alphabetic() || c == '_') => {
                    used.insert(identifier(&rest[k..]));
                    expect_item = false;
                }
                _ => {}
            }
        }
    }
    used.retain(|name| !name.is_empty() && name != "self");
    used
}

/// Every top-level module of `src/` and the modules it uses.
fn module_graph(src: &Path) -> BTreeMap<String, BTreeSet<String>> {
    fn files(path: &Path, found: &mut Vec<std::path::PathBuf>) {
        if path.is_dir() {
            let mut entries: Vec<_> = std::fs::read_dir(path).unwrap().map(|e| e.unwrap().path()).collect();
            entries.sort();
            for entry in entries {
                files(&entry, found);
            }
        } else if path.extension().is_some_and(|e| e == "rs") {
            found.push(path.to_path_buf());
        }
    }
    let mut graph: BTreeMap<String, BTreeSet<String>> = BTreeMap::new();
    let mut found = Vec::new();
    files(src, &mut found);
    for file in found {
        let relative = file.strip_prefix(src).unwrap();
        let top = relative.components().next().unwrap().as_os_str().to_string_lossy();
        let module = top.trim_end_matches(".rs").to_string();
        if module == "lib" || module == "main" {
            continue;
        }
        let code = code_of(&std::fs::read_to_string(&file).unwrap());
        let used = modules_used(&code);
        let edges = graph.entry(module.clone()).or_default();
        edges.extend(used.into_iter().filter(|m| *m != module));
    }
    graph
}

/// Strongly connected components of more than one node (Tarjan), each
/// sorted, in name order.
fn cycles(graph: &BTreeMap<String, BTreeSet<String>>) -> Vec<Vec<String>> {
    struct State<'a> {
        graph: &'a BTreeMap<String, BTreeSet<String>>,
        index: BTreeMap<&'a str, usize>,
        low: BTreeMap<&'a str, usize>,
        stack: Vec<&'a str>,
        on_stack: BTreeSet<&'a str>,
        found: Vec<Vec<String>>,
    }
    fn visit<'a>(state: &mut State<'a>, node: &'a str) {
        let next = state.index.len();
        state.index.insert(node, next);
        state.low.insert(node, next);
        state.stack.push(node);
        state.on_stack.insert(node);
        let graph = state.graph;
        for target in graph.get(node).into_iter().flatten() {
            let target = target.as_str();
            if !graph.contains_key(target) {
                continue;
            }
            if !state.index.contains_key(target) {
                visit(state, target);
                let low = state.low[node].min(state.low[target]);
                state.low.insert(node, low);
            } else if state.on_stack.contains(target) {
                let low = state.low[node].min(state.index[target]);
                state.low.insert(node, low);
            }
        }
        if state.low[node] == state.index[node] {
            let mut component = Vec::new();
            while let Some(top) = state.stack.pop() {
                state.on_stack.remove(top);
                component.push(top.to_string());
                if top == node {
                    break;
                }
            }
            if component.len() > 1 {
                component.sort();
                state.found.push(component);
            }
        }
    }
    let mut state = State {
        graph,
        index: BTreeMap::new(),
        low: BTreeMap::new(),
        stack: Vec::new(),
        on_stack: BTreeSet::new(),
        found: Vec::new(),
    };
    for node in graph.keys() {
        if !state.index.contains_key(node.as_str()) {
            visit(&mut state, node);
        }
    }
    state.found.sort();
    state.found
}

#[test]
fn grouped_and_inline_paths_are_edges_and_comments_are_not() {
    let code = code_of(
        "use crate::{error::{Error, Result}, fit::FitOptions};\n\
         // crate::report is only mentioned here\n\
         /// [`crate::quality`] in a doc link\n\
         let x = crate::windows::CalibrationWindow::new(0.0, 1.0);\n\
         let url = \"https://example.org\"; crate::screen::run();\n\
         #[cfg(test)]\npub(crate) mod tests { use crate::simulate::simulate; }\n",
    );
    let used: Vec<String> = modules_used(&code).into_iter().collect();
    assert_eq!(used, ["error", "fit", "screen", "windows"]);
    let plain = code_of("use crate::fit::X;\n#[cfg(test)]\nmod tests { use crate::simulate::simulate; }\n");
    assert_eq!(modules_used(&plain).into_iter().collect::<Vec<_>>(), ["fit"]);
}

#[test]
fn tarjan_finds_each_cycle_once() {
    let graph: BTreeMap<String, BTreeSet<String>> = [
        ("a", vec!["b"]),
        ("b", vec!["c"]),
        ("c", vec!["a", "d"]),
        ("d", vec!["e"]),
        ("e", vec!["d"]),
        ("f", vec!["a"]),
    ]
    .into_iter()
    .map(|(node, edges)| (node.to_string(), edges.into_iter().map(String::from).collect()))
    .collect();
    assert_eq!(cycles(&graph), [vec!["a", "b", "c"], vec!["d", "e"]]);
}

#[test]
fn the_module_graph_has_no_cycle_beyond_the_known_ones() {
    let src = Path::new(env!("CARGO_MANIFEST_DIR")).join("src");
    let graph = module_graph(&src);
    let found = cycles(&graph);
    println!("{} modules; import cycles:", graph.len());
    for cycle in &found {
        println!("  {}", cycle.join(" ↔ "));
    }
    let known: Vec<Vec<String>> = KNOWN_CYCLES
        .iter()
        .map(|cycle| cycle.iter().map(|m| m.to_string()).collect())
        .collect();
    let new: Vec<&Vec<String>> = found.iter().filter(|c| !known.contains(c)).collect();
    let gone: Vec<&Vec<String>> = known.iter().filter(|c| !found.contains(c)).collect();
    assert!(
        new.is_empty() && gone.is_empty(),
        "import cycles changed: new or grown {new:?}; gone or shrunk (strike them from KNOWN_CYCLES) {gone:?}"
    );
}

/// The interface contract the code refers to ("CONTRACT §n") is in the
/// repository, kept in step with the shared copy beside it.
#[test]
fn the_contract_in_the_repository_is_the_shared_one() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let ours = std::fs::read_to_string(root.join("docs/CONTRACT.md")).expect("docs/CONTRACT.md is in the repository");
    assert!(ours.contains("DETECT.json") && ours.contains("DIAGNOSIS.json"));
    let shared = root.join("../shared/CONTRACT.md");
    match std::fs::read_to_string(&shared) {
        Ok(theirs) => assert!(
            ours == theirs,
            "docs/CONTRACT.md differs from {}: copy the shared one over it and check the code against the change",
            shared.display()
        ),
        Err(_) => println!(
            "{} is absent: docs/CONTRACT.md not compared with the shared copy",
            shared.display()
        ),
    }
}
