//! Docs that stay true: every relative link in the workspace's Markdown (README, BENCHMARKS,
//! `docs/**`, the crates' READMEs, examples) points at a file that exists, and an `#anchor` into
//! a Markdown file at one of its headings (GitHub's slugs); and every `qfleet …` command the
//! docs quote — in a fenced shell block or in inline code — parses with the real CLI.
//!
//! Commands are parsed, not run: `QFLEET_PARSE_ONLY=1` makes `qfleet` parse its arguments
//! exactly as usual and exit 0 without doing anything (a parse error keeps clap's exit code 2;
//! `tools/src/main.rs`). How a quoted command is read:
//! - a fenced block's lines are joined at a trailing `\`, shell comments (` # …`) dropped, and
//!   split into simple commands at `&&`, `||`, `;`, ` | `, `do`, `then`; a command counts when
//!   its program (after `VAR=value`, `sudo`, `nice`, `time`, `exec`) is `qfleet` or ends in
//!   `/qfleet` (`target/release/qfleet`). Inline code is read the same way.
//! - notation is expanded, not skipped: `[--json]` is read as `--json`, `list|echo|hz` as
//!   `list`, placeholders for numbers (`K`, `N`, `STEPS_PER_S`) as `2`, `ADDR:PORT` as
//!   `127.0.0.1:9000`; other capitalised placeholders (`FILE`, `DIR`, `ID`) are strings anyway.
//! - `$VAR` takes the first value of a `for VAR in …` (or `VAR=value`) in the same block, the
//!   first number of `$(seq A B)`; a variable bound nowhere makes the command *skipped*.
//! - a command with `…` or `...` (elided arguments) is *skipped*.
//! - a mention of a subcommand alone in inline code (`qfleet replay`) is checked with `--help`,
//!   inline code naming a command's options without its required arguments (`qfleet join
//!   --json`) by finding each option in that command's `--help`; `qfleet` alone is a name.
//!
//! Skipped commands are counted and printed, and their number must stay at or under
//! [`MAX_SKIPPED`]; a command that stops parsing fails the test with its file and line.

use qfleet_suite::{bin, workspace_files};
use std::collections::{BTreeMap, BTreeSet, HashMap};
use std::path::{Component, Path, PathBuf};
use std::process::Command;

/// Documented commands that cannot be parsed as written (elided arguments, unbound
/// variables): today five, all in `docs/bench/history.md`, which keeps the measurements as they
/// were written. Raise it only with a reason; prefer writing the command out.
const MAX_SKIPPED: usize = 6;

fn root() -> &'static Path {
    Path::new(env!("CARGO_MANIFEST_DIR"))
}

/// Every Markdown file of the workspace with its text.
fn markdown_files() -> Vec<(PathBuf, String)> {
    workspace_files(".md")
        .into_iter()
        .map(|f| {
            let text = std::fs::read_to_string(root().join(&f))
                .unwrap_or_else(|e| panic!("{}: {e}", f.display()));
            (f, text)
        })
        .collect()
}

/// A Markdown file cut into fenced code blocks and prose paragraphs.
#[derive(Debug, PartialEq)]
enum Block {
    /// (info string, first line number, lines)
    Fence(String, usize, Vec<String>),
    /// (first line number, lines)
    Prose(usize, Vec<String>),
}

fn blocks(text: &str) -> Vec<Block> {
    let mut out = Vec::new();
    let mut fence: Option<(String, String, usize, Vec<String>)> = None;
    let mut prose: Option<(usize, Vec<String>)> = None;
    for (i, line) in text.lines().enumerate() {
        let n = i + 1;
        let t = line.trim_start();
        if let Some((marker, info, start, mut lines)) = fence.take() {
            if t.starts_with(marker.as_str())
                && t.trim_start_matches(marker.chars().next().unwrap())
                    .trim()
                    .is_empty()
            {
                out.push(Block::Fence(info, start, lines));
            } else {
                lines.push(line.to_string());
                fence = Some((marker, info, start, lines));
            }
            continue;
        }
        if t.starts_with("```") || t.starts_with("~~~") {
            if let Some((start, lines)) = prose.take() {
                out.push(Block::Prose(start, lines));
            }
            let c = t.chars().next().unwrap();
            let marker: String = t.chars().take_while(|&x| x == c).collect();
            let info = t[marker.len()..].trim().to_string();
            fence = Some((marker, info, n + 1, Vec::new()));
            continue;
        }
        if t.is_empty() {
            if let Some((start, lines)) = prose.take() {
                out.push(Block::Prose(start, lines));
            }
            continue;
        }
        prose
            .get_or_insert((n, Vec::new()))
            .1
            .push(line.to_string());
    }
    if let Some((start, lines)) = prose {
        out.push(Block::Prose(start, lines));
    }
    if let Some((_, info, start, lines)) = fence {
        out.push(Block::Fence(info, start, lines));
    }
    out
}

/// A prose paragraph split into text outside code spans (code spans become a space) and the
/// code spans themselves, each with the line it starts on.
fn split_code_spans(start: usize, lines: &[String]) -> (String, Vec<(usize, String)>) {
    let text = lines.join("\n");
    let chars: Vec<char> = text.chars().collect();
    let mut prose = String::new();
    let mut spans = Vec::new();
    let mut line = start;
    let mut i = 0;
    while i < chars.len() {
        if chars[i] == '\\' && i + 1 < chars.len() {
            prose.push(chars[i]);
            prose.push(chars[i + 1]);
            i += 2;
            continue;
        }
        if chars[i] == '`' {
            let ticks = chars[i..].iter().take_while(|&&c| c == '`').count();
            // the closing run of exactly as many backticks
            let mut j = i + ticks;
            let mut close = None;
            while j < chars.len() {
                if chars[j] == '`' {
                    let run = chars[j..].iter().take_while(|&&c| c == '`').count();
                    if run == ticks {
                        close = Some(j);
                        break;
                    }
                    j += run;
                } else {
                    j += 1;
                }
            }
            if let Some(j) = close {
                let code: String = chars[i + ticks..j].iter().collect();
                spans.push((line, code.replace('\n', " ").trim().to_string()));
                line += code.matches('\n').count();
                prose.push(' ');
                i = j + ticks;
                continue;
            }
            // no closing run: literal backticks
            for _ in 0..ticks {
                prose.push('`');
            }
            i += ticks;
            continue;
        }
        if chars[i] == '\n' {
            line += 1;
        }
        prose.push(chars[i]);
        i += 1;
    }
    (prose, spans)
}

// ---------------------------------------------------------------------------------------------
// links

/// GitHub's anchor for a heading's text: inline Markdown reduced to its text, lower case,
/// everything but letters, digits, `-`, `_` and spaces dropped, spaces to `-`.
fn slug(heading: &str) -> String {
    // [text](url) → text
    let mut text = String::new();
    let mut rest = heading;
    while let Some(open) = rest.find('[') {
        let Some(mid) = rest[open..].find("](") else {
            break;
        };
        let Some(close) = rest[open + mid..].find(')') else {
            break;
        };
        text.push_str(&rest[..open]);
        text.push_str(&rest[open + 1..open + mid]);
        rest = &rest[open + mid + close + 1..];
    }
    text.push_str(rest);
    text.trim()
        .to_lowercase()
        .chars()
        .filter(|c| c.is_alphanumeric() || *c == '-' || *c == '_' || *c == ' ')
        .map(|c| if c == ' ' { '-' } else { c })
        .collect()
}

/// The anchors of a Markdown file's headings, duplicates numbered as GitHub does.
fn anchors(text: &str) -> BTreeSet<String> {
    let mut seen: HashMap<String, usize> = HashMap::new();
    let mut out = BTreeSet::new();
    for b in blocks(text) {
        let Block::Prose(_, lines) = b else { continue };
        for l in lines {
            let t = l.trim_start();
            let hashes = t.chars().take_while(|&c| c == '#').count();
            if !(1..=6).contains(&hashes) || !t[hashes..].starts_with(' ') {
                continue;
            }
            let title = t[hashes..].trim().trim_end_matches('#').trim();
            let base = slug(&title.replace('`', ""));
            let k = seen.entry(base.clone()).or_insert(0);
            out.insert(if *k == 0 {
                base.clone()
            } else {
                format!("{base}-{k}")
            });
            *k += 1;
        }
    }
    out
}

/// Link targets in prose: `[text](target)`, `![alt](target "title")`, `[ref]: target`.
fn link_targets(prose: &str) -> Vec<String> {
    let mut out = Vec::new();
    let mut rest = prose;
    while let Some(at) = rest.find("](") {
        let after = &rest[at + 2..];
        let mut depth = 0;
        let mut end = None;
        for (i, c) in after.char_indices() {
            match c {
                '(' => depth += 1,
                ')' if depth == 0 => {
                    end = Some(i);
                    break;
                }
                ')' => depth -= 1,
                '\n' => break,
                _ => {}
            }
        }
        if let Some(end) = end {
            let inner = after[..end].trim();
            let target = inner
                .strip_prefix('<')
                .and_then(|t| t.split_once('>').map(|(t, _)| t))
                .unwrap_or_else(|| inner.split_whitespace().next().unwrap_or(""));
            out.push(target.to_string());
            rest = &after[end..];
        } else {
            rest = after;
        }
    }
    for l in prose.lines() {
        let t = l.trim_start();
        if let Some(close) = t.strip_prefix('[').and_then(|r| r.find("]:"))
            && !t[1..close + 1].is_empty()
            && let Some(target) = t[close + 3..].split_whitespace().next()
        {
            out.push(target.to_string());
        }
    }
    out
}

/// `a/b/../c` → `a/c`, without touching the file system (a link must not climb out of the
/// workspace).
fn normalise(p: &Path) -> Option<PathBuf> {
    let mut out = PathBuf::new();
    for c in p.components() {
        match c {
            Component::ParentDir => {
                if !out.pop() {
                    return None;
                }
            }
            Component::CurDir => {}
            Component::Normal(x) => out.push(x),
            _ => return None,
        }
    }
    Some(out)
}

#[test]
fn every_relative_link_and_anchor_in_the_docs_resolves() {
    let files = markdown_files();
    let texts: BTreeMap<PathBuf, &str> =
        files.iter().map(|(f, t)| (f.clone(), t.as_str())).collect();
    let mut anchor_cache: HashMap<PathBuf, BTreeSet<String>> = HashMap::new();
    let mut broken = Vec::new();
    let mut checked = 0;
    let mut anchors_checked = 0;
    for (file, text) in &files {
        for b in blocks(text) {
            let Block::Prose(start, lines) = b else {
                continue;
            };
            let (prose, _) = split_code_spans(start, &lines);
            for target in link_targets(&prose) {
                if target.is_empty() || target.contains("://") || target.starts_with("mailto:") {
                    continue;
                }
                checked += 1;
                let (path, anchor) = match target.split_once('#') {
                    Some((p, a)) => (p, Some(a)),
                    None => (target.as_str(), None),
                };
                let dest = if path.is_empty() {
                    Some(file.clone())
                } else {
                    normalise(&file.parent().unwrap_or(Path::new("")).join(path))
                };
                let Some(dest) = dest else {
                    broken.push(format!(
                        "{}: {target}: outside the workspace",
                        file.display()
                    ));
                    continue;
                };
                if !root().join(&dest).exists() {
                    broken.push(format!("{}: {target}: no such file", file.display()));
                    continue;
                }
                if let Some(anchor) = anchor
                    && dest.extension().is_some_and(|e| e == "md")
                {
                    anchors_checked += 1;
                    let known = anchor_cache.entry(dest.clone()).or_insert_with(|| {
                        let t = texts.get(&dest).map(|t| t.to_string()).unwrap_or_else(|| {
                            std::fs::read_to_string(root().join(&dest)).unwrap_or_default()
                        });
                        anchors(&t)
                    });
                    if !known.contains(anchor) {
                        broken.push(format!(
                            "{}: {target}: no heading with anchor #{anchor} in {}",
                            file.display(),
                            dest.display()
                        ));
                    }
                }
            }
        }
    }
    say(&format!(
        "docs: {checked} relative links in {} Markdown files checked, {anchors_checked} of them with an anchor",
        files.len()
    ));
    assert!(broken.is_empty(), "broken links:\n{}", broken.join("\n"));
    assert!(
        checked >= 50,
        "only {checked} relative links found: is the scan broken?"
    );
}

// ---------------------------------------------------------------------------------------------
// commands

/// A shell word or an operator.
#[derive(Debug, Clone, PartialEq)]
enum Tok {
    Word(String),
    Op,
}

/// Splits a shell line into words and operators; quotes are removed, `$(…)` is kept whole,
/// `a|b|c` inside a word (notation for alternatives) keeps `a`, and redirections are dropped.
fn lex(line: &str) -> Vec<Tok> {
    let chars: Vec<char> = line.chars().collect();
    let mut toks = Vec::new();
    let mut word = String::new();
    let mut in_word = false;
    let mut i = 0;
    let flush = |word: &mut String, in_word: &mut bool, toks: &mut Vec<Tok>| {
        if *in_word {
            toks.push(Tok::Word(std::mem::take(word)));
            *in_word = false;
        }
    };
    while i < chars.len() {
        let c = chars[i];
        match c {
            // a block's lines are read joined by newlines: a newline ends a word too
            ' ' | '\t' | '\n' | '\r' => {
                flush(&mut word, &mut in_word, &mut toks);
                i += 1;
            }
            '\'' => {
                in_word = true;
                i += 1;
                while i < chars.len() && chars[i] != '\'' {
                    word.push(chars[i]);
                    i += 1;
                }
                i += 1;
            }
            '"' => {
                in_word = true;
                i += 1;
                while i < chars.len() && chars[i] != '"' {
                    if chars[i] == '\\' && i + 1 < chars.len() {
                        i += 1;
                    }
                    word.push(chars[i]);
                    i += 1;
                }
                i += 1;
            }
            '\\' if i + 1 < chars.len() => {
                in_word = true;
                word.push(chars[i + 1]);
                i += 2;
            }
            '$' if chars.get(i + 1) == Some(&'(') => {
                in_word = true;
                let mut depth = 0;
                while i < chars.len() {
                    word.push(chars[i]);
                    if chars[i] == '(' {
                        depth += 1;
                    } else if chars[i] == ')' {
                        depth -= 1;
                        if depth == 0 {
                            i += 1;
                            break;
                        }
                    }
                    i += 1;
                }
            }
            '|' if in_word && chars.get(i + 1).is_some_and(|c| c.is_alphanumeric()) => {
                // `list|echo|hz`: the first alternative
                while i < chars.len() && !chars[i].is_whitespace() {
                    i += 1;
                }
            }
            '&' | '|' | ';' => {
                flush(&mut word, &mut in_word, &mut toks);
                while i < chars.len() && matches!(chars[i], '&' | '|' | ';') {
                    i += 1;
                }
                toks.push(Tok::Op);
            }
            '>' | '<' => {
                // a redirection: `> f`, `2>&1`, `>/dev/null`; drop it and its target
                if in_word && word.chars().all(|c| c.is_ascii_digit()) {
                    word.clear();
                    in_word = false;
                }
                flush(&mut word, &mut in_word, &mut toks);
                while i < chars.len() && matches!(chars[i], '>' | '<' | '&') {
                    i += 1;
                }
                while i < chars.len() && chars[i].is_whitespace() {
                    i += 1;
                }
                while i < chars.len() && !chars[i].is_whitespace() {
                    i += 1;
                }
            }
            _ => {
                in_word = true;
                word.push(c);
                i += 1;
            }
        }
    }
    flush(&mut word, &mut in_word, &mut toks);
    toks
}

/// Drops a shell comment: `#` at the start of a word, outside quotes.
fn strip_comment(line: &str) -> &str {
    let mut quote = None;
    let mut prev = ' ';
    for (i, c) in line.char_indices() {
        match (quote, c) {
            (None, '\'' | '"') => quote = Some(c),
            (Some(q), c) if c == q => quote = None,
            (None, '#') if prev.is_whitespace() => return &line[..i],
            _ => {}
        }
        prev = c;
    }
    line
}

/// One `qfleet …` command found in the docs.
#[derive(Debug, Clone)]
struct Found {
    at: String,
    quoted: String,
    /// in inline code (else in a fenced block)
    inline: bool,
}

/// Why a command did not parse.
#[derive(Debug)]
struct ParseError {
    /// clap's first error line
    line: String,
    /// only something required is missing: a required argument, or an option's value
    incomplete: bool,
}

/// Parses `args` with the real CLI and nothing else (`QFLEET_PARSE_ONLY=1`).
fn parses(qfleet: &Path, args: &[String]) -> Result<(), ParseError> {
    let out = Command::new(qfleet)
        .current_dir(root())
        .env("QFLEET_PARSE_ONLY", "1")
        .args(args)
        .output()
        .expect("run qfleet");
    if out.status.success() {
        return Ok(());
    }
    let err = String::from_utf8_lossy(&out.stderr);
    Err(ParseError {
        line: err.lines().next().unwrap_or("").to_string(),
        incomplete: out.status.code() == Some(2)
            && (err.contains("required arguments were not provided")
                || err.contains("a value is required for")),
    })
}

/// Whether every `--option` in `args` is one its (sub)command's `--help` lists.
fn options_exist(qfleet: &Path, args: &[String]) -> Result<(), String> {
    let path: Vec<&String> = args.iter().take_while(|a| !a.starts_with('-')).collect();
    let out = Command::new(qfleet)
        .args(&path)
        .arg("--help")
        .output()
        .expect("run qfleet --help");
    let help = String::from_utf8_lossy(&out.stdout);
    let unknown: Vec<&str> = args
        .iter()
        .filter(|a| a.starts_with("--"))
        .map(|a| a.split('=').next().unwrap())
        .filter(|o| {
            !help
                .split(|c: char| !(c.is_alphanumeric() || c == '-'))
                .any(|w| w == *o)
        })
        .collect();
    if out.status.success() && unknown.is_empty() {
        Ok(())
    } else {
        Err(format!(
            "qfleet {} has no option {}",
            path.iter()
                .map(|s| s.as_str())
                .collect::<Vec<_>>()
                .join(" "),
            unknown.join(", ")
        ))
    }
}

/// What to do with a quoted command.
#[derive(Debug)]
enum Verdict {
    Parse(Vec<String>),
    Skip(String),
}

/// The simple commands of a shell text whose program is qfleet, as raw words.
fn qfleet_commands(text: &str) -> Vec<Vec<String>> {
    let mut out = Vec::new();
    let mut cmd: Vec<String> = Vec::new();
    let mut finish = |cmd: &mut Vec<String>| {
        let words = std::mem::take(cmd);
        let mut i = 0;
        // what comes before the program: `VAR=value`, `sudo`, `nice`, `do` of a loop, …
        while let Some(w) = words.get(i).map(String::as_str) {
            let assignment = !w.starts_with('-')
                && w.split_once('=').is_some_and(|(v, _)| {
                    !v.is_empty() && v.chars().all(|c| c.is_ascii_alphanumeric() || c == '_')
                });
            let prefix = matches!(
                w,
                "sudo" | "nice" | "time" | "exec" | "then" | "do" | "else"
            );
            if !(assignment || prefix) {
                break;
            }
            i += 1;
        }
        if let Some(prog) = words.get(i)
            && (prog == "qfleet" || prog.ends_with("/qfleet"))
        {
            out.push(words[i + 1..].to_vec());
        }
    };
    for tok in lex(text) {
        match tok {
            Tok::Word(w) => cmd.push(w),
            Tok::Op => finish(&mut cmd),
        }
    }
    finish(&mut cmd);
    out
}

/// Shell variables bound in a block: `for X in a b` (first value; `$(seq A B)` gives A) and
/// `X=value`.
fn bindings(text: &str) -> HashMap<String, String> {
    let mut vars = HashMap::new();
    let words: Vec<String> = lex(text)
        .into_iter()
        .filter_map(|t| match t {
            Tok::Word(w) => Some(w),
            Tok::Op => None,
        })
        .collect();
    for (i, w) in words.iter().enumerate() {
        if w == "for"
            && words.get(i + 2).is_some_and(|x| x == "in")
            && let (Some(var), Some(first)) = (words.get(i + 1), words.get(i + 3))
        {
            let value = match first.strip_prefix("$(seq ") {
                Some(r) => r.split_whitespace().next().unwrap_or("1").to_string(),
                None => first.clone(),
            };
            vars.insert(var.clone(), value);
        } else if let Some((k, v)) = w.split_once('=')
            && !k.is_empty()
            && k.chars().all(|c| c.is_ascii_uppercase() || c == '_')
        {
            vars.insert(k.to_string(), v.to_string());
        }
    }
    vars
}

/// A placeholder's stand-in value, for the placeholders the docs use: one capital letter or
/// `STEPS_PER_S` for a number, `ADDR:PORT` (or `HOST:PORT`) for an address, `ENDPOINT` for a
/// Zenoh endpoint.
fn placeholder(word: &str) -> Option<String> {
    let one_capital = word.len() == 1 && word.chars().all(|c| c.is_ascii_uppercase());
    if one_capital || word == "STEPS_PER_S" {
        return Some("2".into());
    }
    if word == "ENDPOINT" {
        return Some("tcp/127.0.0.1:7447".into());
    }
    if word == "ADDR:PORT" {
        return Some("127.0.0.1:9000".into());
    }
    word.strip_suffix(":PORT")
        .map(|host| format!("{host}:9000"))
}

/// Reads notation (`[opt]`, placeholders, variables) into arguments, or says why it cannot.
fn verdict(words: &[String], vars: &HashMap<String, String>, inline: bool) -> Verdict {
    if words.iter().any(|w| w.contains('…') || w.contains("...")) {
        return Verdict::Skip("elided arguments (…)".into());
    }
    if inline && words.len() == 1 && !words[0].starts_with('-') {
        return Verdict::Parse(vec![words[0].clone(), "--help".into()]);
    }
    let mut args = Vec::new();
    for w in words {
        let w = w.trim_start_matches('[').trim_end_matches(']');
        if w.is_empty() {
            continue;
        }
        if let Some(v) = placeholder(w) {
            args.push(v);
            continue;
        }
        // `--apply/--merge`: either option, read as the first
        let w = match w.split_once("/--") {
            Some((first, _)) if w.starts_with("--") => first,
            _ => w,
        };
        // $VAR, ${VAR}, $(seq …) anywhere in the word
        let mut out = String::new();
        let mut rest = w;
        while let Some(at) = rest.find('$') {
            out.push_str(&rest[..at]);
            let after = &rest[at + 1..];
            let (name, len) = if let Some(r) = after.strip_prefix('{') {
                let end = r.find('}').unwrap_or(r.len());
                (&r[..end], end + 2)
            } else if after.starts_with('(') {
                return Verdict::Skip(format!("command substitution in {w}"));
            } else {
                let end = after
                    .find(|c: char| !(c.is_ascii_alphanumeric() || c == '_'))
                    .unwrap_or(after.len());
                (&after[..end], end)
            };
            match vars.get(name) {
                Some(v) => out.push_str(v),
                None => return Verdict::Skip(format!("${name} is bound nowhere in its block")),
            }
            rest = &after[len..];
        }
        out.push_str(rest);
        args.push(out);
    }
    Verdict::Parse(args)
}

/// Every quoted `qfleet …` command of the docs, with where it is.
fn documented_commands() -> Vec<(Found, Verdict)> {
    let mut out = Vec::new();
    for (file, text) in markdown_files() {
        for b in blocks(&text) {
            match b {
                Block::Fence(info, start, lines) => {
                    let lang = info.split_whitespace().next().unwrap_or("");
                    if !matches!(lang, "" | "sh" | "bash" | "shell" | "console" | "text") {
                        continue;
                    }
                    // join continuations, drop comments, keep each command's first line number
                    let mut joined: Vec<(usize, String)> = Vec::new();
                    let mut open = false;
                    for (k, l) in lines.iter().enumerate() {
                        let l = strip_comment(l).trim_end();
                        let (body, cont) = match l.strip_suffix('\\') {
                            Some(b) => (b, true),
                            None => (l, false),
                        };
                        if open {
                            let last = joined.last_mut().unwrap();
                            last.1.push(' ');
                            last.1.push_str(body.trim());
                        } else {
                            joined.push((start + k, body.to_string()));
                        }
                        open = cont;
                    }
                    let all: String = joined
                        .iter()
                        .map(|(_, l)| l.as_str())
                        .collect::<Vec<_>>()
                        .join("\n");
                    let vars = bindings(&all);
                    for (n, line) in joined {
                        for words in qfleet_commands(&line) {
                            let found = Found {
                                at: format!("{}:{n}", file.display()),
                                quoted: line.trim().to_string(),
                                inline: false,
                            };
                            let v = verdict(&words, &vars, false);
                            out.push((found, v));
                        }
                    }
                }
                Block::Prose(start, lines) => {
                    let (_, spans) = split_code_spans(start, &lines);
                    for (n, code) in spans {
                        let vars = bindings(&code);
                        for words in qfleet_commands(&code) {
                            if words.is_empty() {
                                // the program's name alone (`qfleet`), not a command
                                continue;
                            }
                            let found = Found {
                                at: format!("{}:{n}", file.display()),
                                quoted: code.clone(),
                                inline: true,
                            };
                            out.push((found, verdict(&words, &vars, true)));
                        }
                    }
                }
            }
        }
    }
    out
}

/// A line on the real stderr, shown in every `cargo test` run (the harness captures
/// `eprintln!`).
fn say(line: &str) {
    use std::io::Write;
    let _ = std::io::stderr()
        .lock()
        .write_all(format!("{line}\n").as_bytes());
}

#[test]
fn every_qfleet_command_in_the_docs_parses() {
    let qfleet = bin("qfleet");
    let found = documented_commands();
    let mut parsed: BTreeMap<Vec<String>, Result<(), ParseError>> = BTreeMap::new();
    let mut failed = Vec::new();
    let mut skipped = Vec::new();
    let mut checked = 0;
    let mut mentions = 0;
    for (f, v) in &found {
        match v {
            Verdict::Skip(why) => skipped.push(format!("{}: `{}`: {why}", f.at, f.quoted)),
            Verdict::Parse(args) => {
                checked += 1;
                let result = parsed
                    .entry(args.clone())
                    .or_insert_with(|| parses(&qfleet, args));
                let result = match result {
                    // inline code that names options of a command (`qfleet join --json`) rather
                    // than quoting a whole command: each option must be one the command has
                    Err(e) if f.inline && e.incomplete => {
                        mentions += 1;
                        options_exist(&qfleet, args)
                    }
                    Err(e) => Err(e.line.clone()),
                    Ok(()) => Ok(()),
                };
                if let Err(e) = result {
                    failed.push(format!(
                        "{}: `{}` (read as qfleet {}): {e}",
                        f.at,
                        f.quoted,
                        args.join(" ")
                    ));
                }
            }
        }
    }
    say(&format!(
        "docs: {} qfleet commands quoted, {checked} checked ({} distinct; {mentions} of them \
         options named in inline code, checked against the command's --help), {} skipped",
        found.len(),
        parsed.len(),
        skipped.len()
    ));
    for s in &skipped {
        say(&format!("docs: skipped {s}"));
    }
    assert!(
        failed.is_empty(),
        "{} documented command(s) do not parse:\n{}",
        failed.len(),
        failed.join("\n")
    );
    assert!(
        skipped.len() <= MAX_SKIPPED,
        "{} documented commands cannot be parsed as written (at most {MAX_SKIPPED}):\n{}",
        skipped.len(),
        skipped.join("\n")
    );
    assert!(
        checked >= 40,
        "only {checked} commands found: is the scan broken?"
    );
}

#[test]
fn a_command_that_does_not_parse_is_caught() {
    // the switch the test relies on: parse only, and a parse error still fails
    let qfleet = bin("qfleet");
    let run = |args: &[&str]| {
        Command::new(&qfleet)
            .env("QFLEET_PARSE_ONLY", "1")
            .args(args)
            .output()
            .expect("run qfleet")
            .status
            .code()
    };
    assert_eq!(
        run(&["run", "--robots", "4", "--map", "builtin:paper-30"]),
        Some(0)
    );
    assert_eq!(run(&["run", "--robots", "four"]), Some(2));
    assert_eq!(run(&["no-such-command"]), Some(2));
}

#[test]
fn the_readers_of_markdown_and_shell_read_what_the_docs_write() {
    // GitHub's slugs
    assert_eq!(slug("Exit codes"), "exit-codes");
    assert_eq!(
        slug("Held-out results (N = 1000, 10 seeds, 42 held-out maps of sides 10–32)"),
        "held-out-results-n--1000-10-seeds-42-held-out-maps-of-sides-1032"
    );
    assert_eq!(
        slug("In Foxglove: live, recorded, replayed"),
        "in-foxglove-live-recorded-replayed"
    );
    assert_eq!(
        slug("Sweeps inside episodes (--sweep-every, since 09:20 UTC)"),
        "sweeps-inside-episodes---sweep-every-since-0920-utc"
    );
    let a = anchors("# A\n\n## Same\n\n```\n# not a heading\n```\n\n## Same\n");
    assert!(
        a.contains("a") && a.contains("same") && a.contains("same-1"),
        "{a:?}"
    );
    assert!(!a.contains("not-a-heading"));
    // links, not in code
    let (prose, spans) = split_code_spans(1, &["see [x](docs/a.md#b) and `[y](no.md)`".into()]);
    assert_eq!(link_targets(&prose), ["docs/a.md#b"]);
    assert_eq!(spans, [(1, "[y](no.md)".to_string())]);
    // commands
    let words = |s: &str| qfleet_commands(s);
    assert_eq!(
        words(strip_comment(
            "cargo build && target/release/qfleet run --json > o 2>&1 # c"
        )),
        [vec!["run".to_string(), "--json".into()]]
    );
    assert_eq!(
        words(strip_comment(
            "nice qfleet eval --list   # the configurations"
        )),
        [vec!["eval".to_string(), "--list".into()]]
    );
    assert_eq!(
        words("qfleet topic list|echo|hz --run-id ID [robot/state]"),
        [vec![
            "topic".to_string(),
            "list".into(),
            "--run-id".into(),
            "ID".into(),
            "[robot/state]".into()
        ]]
    );
    assert_eq!(words("qfleet clean | head -2"), [vec!["clean".to_string()]]);
    assert!(words("qfleet-coordinator --plan p.json").is_empty());
    // a loop on the block's second line binds too (its lines are joined by newlines)
    let vars = bindings("cargo build\nfor l in a b; do\n  qfleet bench --only $l\ndone");
    assert_eq!(vars.get("l").map(String::as_str), Some("a"));
    let vars = bindings("for s in $(seq 1 20); do qfleet learn --seed $s; done");
    match verdict(
        &["learn".into(), "--seed".into(), "$s".into()],
        &vars,
        false,
    ) {
        Verdict::Parse(a) => assert_eq!(a, ["learn", "--seed", "1"]),
        v => panic!("{v:?}"),
    }
    assert!(matches!(
        verdict(
            &["learn".into(), "--map".into(), "$M/x.map".into()],
            &HashMap::new(),
            false
        ),
        Verdict::Skip(_)
    ));
    assert!(matches!(
        verdict(&["experiment".into(), "…".into()], &HashMap::new(), true),
        Verdict::Skip(_)
    ));
}
