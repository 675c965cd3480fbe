//! Docs that cannot go stale: every command line in `README.md` and `docs/*.md` parses against
//! the real argument parsers (clap's own, through the services' libraries), every config key
//! they name is a key of the run-file structs (deserialised with `deny_unknown_fields`), every
//! ```toml block is a valid run-file fragment, every repository path and relative link exists,
//! and every duration the README quotes comes from `docs/results/durations.toml`.
//!
//! The checks are functions of the text, so the tests below also feed them misspelt copies and
//! require that each one fails.

use std::path::{Path, PathBuf};

use clap::CommandFactory;
use pulldown_cmark::{CodeBlockKind, Event, Parser, Tag, TagEnd};

fn root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../..")
}

/// `README.md` and the guides (`docs/*.md`; `docs/results/` holds measurements, not guides).
fn doc_files() -> Vec<PathBuf> {
    let mut files = vec![root().join("README.md")];
    let mut guides: Vec<PathBuf> = std::fs::read_dir(root().join("docs"))
        .expect("docs/ exists")
        .map(|e| e.expect("readable docs/ entry").path())
        .filter(|p| p.extension().is_some_and(|e| e == "md"))
        .collect();
    guides.sort();
    files.extend(guides);
    files
}

/// What the checks look at in one Markdown file.
#[derive(Debug, Default)]
struct Snippets {
    /// Command lines: the lines of ```sh blocks (continuations joined) and inline code that
    /// starts with a terl binary or `./deploy/`.
    commands: Vec<String>,
    /// ```toml blocks.
    toml_blocks: Vec<String>,
    /// Every inline code span.
    inline: Vec<String>,
    /// Link destinations.
    links: Vec<String>,
    /// Prose (text outside code).
    prose: String,
}

const COMMAND_PREFIXES: [&str; 5] = [
    "terl ",
    "terl-learner ",
    "terl-actor ",
    "terl-selector ",
    "./deploy/",
];

fn snippets(markdown: &str) -> Snippets {
    let mut s = Snippets::default();
    let mut block: Option<(String, String)> = None;
    for event in Parser::new(markdown) {
        match event {
            Event::Start(Tag::CodeBlock(kind)) => {
                let lang = match kind {
                    CodeBlockKind::Fenced(l) => l.to_string(),
                    CodeBlockKind::Indented => String::new(),
                };
                block = Some((lang, String::new()));
            }
            Event::Text(t) if block.is_some() => block.as_mut().unwrap().1.push_str(&t),
            Event::End(TagEnd::CodeBlock) => {
                let (lang, text) = block.take().unwrap();
                match lang.as_str() {
                    "sh" | "bash" | "shell" => s.commands.extend(shell_lines(&text)),
                    "toml" => s.toml_blocks.push(text),
                    _ => {}
                }
            }
            Event::Code(c) => {
                if COMMAND_PREFIXES.iter().any(|p| c.starts_with(p)) {
                    s.commands.push(c.to_string());
                }
                s.inline.push(c.to_string());
            }
            Event::Start(Tag::Link { dest_url, .. } | Tag::Image { dest_url, .. }) => {
                s.links.push(dest_url.to_string())
            }
            Event::Text(t) => {
                s.prose.push_str(&t);
                s.prose.push(' ');
            }
            Event::SoftBreak | Event::HardBreak => s.prose.push(' '),
            _ => {}
        }
    }
    s
}

/// The logical lines of a shell block: `\` continuations joined, blank and comment lines out.
fn shell_lines(text: &str) -> Vec<String> {
    let mut out = Vec::new();
    let mut cur = String::new();
    for line in text.lines() {
        let line = line.trim_end();
        if let Some(head) = line.strip_suffix('\\') {
            cur.push_str(head);
            cur.push(' ');
            continue;
        }
        cur.push_str(line);
        let l = cur.trim().to_string();
        cur.clear();
        if !l.is_empty() && !l.starts_with('#') {
            out.push(l);
        }
    }
    out
}

/// Drops a `# comment` that is outside quotes.
fn strip_comment(line: &str) -> &str {
    let (mut single, mut double) = (false, false);
    let mut prev = ' ';
    for (i, c) in line.char_indices() {
        match c {
            '\'' if !double => single = !single,
            '"' if !single => double = !double,
            '#' if !single && !double && prev.is_whitespace() => return &line[..i],
            _ => {}
        }
        prev = c;
    }
    line
}

/// Checks one command line; `Ok(false)` for a line of another tool (not checked).
fn check_command(line: &str) -> Result<bool, String> {
    if line.contains('…') || line.contains("...") {
        return Err(format!("an ellipsis in a command line: {line}"));
    }
    let words =
        shlex::split(strip_comment(line)).ok_or_else(|| format!("unbalanced quotes in: {line}"))?;
    let mut checked = false;
    for part in words.split(|w| matches!(w.as_str(), "|" | "||" | "&&" | ";" | "&")) {
        let argv: Vec<&str> = part
            .iter()
            .map(String::as_str)
            .skip_while(|w| is_env_assignment(w))
            .collect();
        if argv.is_empty() {
            continue;
        }
        checked |= check_argv(&argv).map_err(|e| format!("{e}\n  in: {line}"))?;
    }
    Ok(checked)
}

fn is_env_assignment(w: &str) -> bool {
    w.split_once('=').is_some_and(|(k, _)| {
        !k.is_empty()
            && k.chars()
                .all(|c| c.is_ascii_uppercase() || c.is_ascii_digit() || c == '_')
    })
}

fn clap_parse(cmd: clap::Command, argv: &[&str]) -> Result<bool, String> {
    use clap::error::ErrorKind;
    match cmd.try_get_matches_from(argv) {
        Ok(_) => Ok(true),
        Err(e) if matches!(e.kind(), ErrorKind::DisplayHelp | ErrorKind::DisplayVersion) => {
            Ok(true)
        }
        // `terl bench` alone and the like print their subcommands' list.
        Err(e) if e.kind() == ErrorKind::DisplayHelpOnMissingArgumentOrSubcommand => Ok(true),
        Err(e) => Err(e.render().to_string()),
    }
}

fn check_argv(argv: &[&str]) -> Result<bool, String> {
    let program = argv[0].strip_prefix("target/release/").unwrap_or(argv[0]);
    match program {
        "terl" => clap_parse(terl_cli::Cli::command(), argv),
        "terl-learner" => clap_parse(terl_learner::args::Args::command(), argv),
        "terl-actor" => clap_parse(terl_actor::args::Args::command(), argv),
        "terl-selector" => clap_parse(terl_selector::args::Args::command(), argv),
        // The launcher script hands its arguments to `terl cluster up`.
        "./deploy/local-cluster.sh" => {
            let mut v = vec!["terl", "cluster", "up"];
            v.extend(&argv[1..]);
            clap_parse(terl_cli::Cli::command(), &v)
        }
        p if p.starts_with("./deploy/") || p.starts_with("deploy/") => {
            let script = root().join(p.trim_start_matches("./"));
            let text =
                std::fs::read_to_string(&script).map_err(|e| format!("no script {p}: {e}"))?;
            for flag in argv[1..].iter().filter(|w| w.starts_with("--")) {
                let name = flag.split('=').next().unwrap();
                if !script_knows(&text, name) {
                    return Err(format!("{p} has no option {name}"));
                }
            }
            Ok(true)
        }
        _ => Ok(false),
    }
}

/// Whether a shell script's option parsing handles `flag`: a `case` arm such as
/// `--seeds) seeds=$2; shift 2 ;;` or `--no-build|-h|--help) ;;` names it.
fn script_knows(text: &str, flag: &str) -> bool {
    text.lines().any(|line| {
        let line = line.trim_start();
        line.starts_with('-')
            && line
                .split_once(')')
                .is_some_and(|(pattern, _)| pattern.split('|').any(|p| p.trim() == flag))
    })
}

/// A minimal run file that the checked keys are added to.
const BASE: &str = "tasks = \"mt10\"\nnum_envs = 10\n";

fn parse_run_file(text: &str) -> Result<terl_runtime::RunConfig, String> {
    toml::from_str(text).map_err(|e| e.to_string())
}

/// A ```toml block: a run-file fragment that deserialises into the run file as it is.
fn check_toml_block(block: &str) -> Result<(), String> {
    let has_top_level = |k: &str| {
        block
            .lines()
            .take_while(|l| !l.trim_start().starts_with('['))
            .any(|l| l.trim_start().starts_with(k))
    };
    let mut text = String::new();
    if !has_top_level("tasks") {
        text.push_str("tasks = \"mt10\"\n");
    }
    if !has_top_level("num_envs") {
        text.push_str("num_envs = 10\n");
    }
    // The block's own top-level keys must come before any table of its own.
    text.push_str(block);
    parse_run_file(&text)
        .map(|_| ())
        .map_err(|e| format!("{e}\n  block:\n{block}"))
}

/// An inline `[section] key` or `[section] key = value`: the key exists in that section (and
/// the value, when written, is valid there).
fn check_config_key(span: &str) -> Option<Result<(), String>> {
    let rest = span.strip_prefix('[')?;
    let (section, rest) = rest.split_once("] ")?;
    if section.is_empty()
        || !section
            .chars()
            .all(|c| c.is_ascii_lowercase() || c.is_ascii_digit() || c == '_' || c == '.')
    {
        return None;
    }
    let (key, value) = match rest.split_once(" = ") {
        Some((k, v)) => (k.trim(), Some(v.trim())),
        None => (rest.trim(), None),
    };
    if key.is_empty()
        || !key
            .chars()
            .all(|c| c.is_ascii_lowercase() || c.is_ascii_digit() || c == '_')
    {
        return None;
    }
    let probe = value.unwrap_or("\"docs-probe\"");
    let text = format!("{BASE}[{section}]\n{key} = {probe}\n");
    Some(match parse_run_file(&text) {
        Ok(_) => Ok(()),
        Err(e) if value.is_none() && !e.contains("unknown field") => Ok(()),
        Err(e) => Err(format!("`{span}`: {e}")),
    })
}

const PATH_PREFIXES: [&str; 7] = [
    "deploy/",
    "docs/",
    "crates/",
    "services/",
    "tests/",
    "proto/",
    "assets/",
];

/// An inline path into the repository exists (`path:line` and `path#anchor` allowed; spans
/// with placeholders or globs are not paths to check).
fn check_path(span: &str) -> Option<Result<(), String>> {
    let first = span.split_whitespace().next()?;
    if !PATH_PREFIXES.iter().any(|p| first.starts_with(p))
        || first.contains(['<', '*', '{', '$'])
        || span.contains(' ')
    {
        return None;
    }
    let path = first
        .split(['#', ':'])
        .next()
        .unwrap()
        .trim_end_matches([',', '.', ')']);
    // `assets/metaworld` and `.deps` are made by deploy/setup.sh, not committed.
    if path.starts_with("assets/") {
        return None;
    }
    Some(if root().join(path).exists() {
        Ok(())
    } else {
        Err(format!(
            "`{span}`: no such file or folder in the repository"
        ))
    })
}

fn check_link(file: &Path, dest: &str) -> Option<Result<(), String>> {
    if dest.contains("://") || dest.starts_with('#') || dest.starts_with("mailto:") {
        return None;
    }
    let path = dest.split('#').next().unwrap();
    let target = file.parent().unwrap().join(path);
    Some(if target.exists() {
        Ok(())
    } else {
        Err(format!(
            "link to {dest}: {} does not exist",
            target.display()
        ))
    })
}

/// Durations in prose: minutes, hours or days, as digits or words ("35–73 minutes", "about two
/// days", "an hour"), with a leading "about"/"~" kept.
fn durations(prose: &str) -> Vec<String> {
    let words: Vec<&str> = prose.split_whitespace().collect();
    let units = [
        "min", "mins", "minute", "minutes", "hour", "hours", "h", "day", "days",
    ];
    let numberish = |w: &str| {
        w.chars().next().is_some_and(|c| c.is_ascii_digit())
            || matches!(
                w,
                "a" | "an" | "one" | "two" | "three" | "four" | "five" | "ten" | "half"
            )
    };
    let mut out = Vec::new();
    for (i, w) in words.iter().enumerate() {
        let unit = w.trim_end_matches([',', '.', ';', ':', ')']);
        if i == 0 || !units.contains(&unit) || !numberish(words[i - 1]) {
            continue;
        }
        let mut start = i - 1;
        if start > 0 && matches!(words[start - 1], "about" | "~" | "under" | "within") {
            start -= 1;
        }
        let mut phrase = words[start..i].join(" ");
        phrase.push(' ');
        phrase.push_str(unit);
        out.push(phrase);
    }
    out
}

#[derive(Debug, serde::Deserialize)]
struct DurationsFile {
    duration: Vec<DurationEntry>,
}

#[derive(Debug, serde::Deserialize)]
#[allow(dead_code)]
struct DurationEntry {
    what: String,
    quoted: String,
    measured: String,
    source: String,
}

fn check_durations(readme_prose: &str, file: &DurationsFile) -> Vec<String> {
    durations(readme_prose)
        .into_iter()
        .filter(|d| !file.duration.iter().any(|e| e.quoted.contains(d.as_str())))
        .map(|d| format!("README.md quotes \"{d}\", which docs/results/durations.toml does not"))
        .collect()
}

/// Every check of one file; the list of failures (empty: the file is in order).
fn check_file(file: &Path, markdown: &str) -> Vec<String> {
    let s = snippets(markdown);
    let mut errors = Vec::new();
    let name = file
        .strip_prefix(root())
        .unwrap_or(file)
        .display()
        .to_string();
    let mut push = |r: Result<(), String>| {
        if let Err(e) = r {
            errors.push(format!("{name}: {e}"));
        }
    };
    for c in &s.commands {
        push(check_command(c).map(|_| ()));
    }
    for b in &s.toml_blocks {
        push(check_toml_block(b));
    }
    for span in &s.inline {
        if let Some(r) = check_config_key(span) {
            push(r);
        }
        if let Some(r) = check_path(span) {
            push(r);
        }
    }
    for l in &s.links {
        if let Some(r) = check_link(file, l) {
            push(r);
        }
    }
    errors
}

fn durations_file() -> DurationsFile {
    let text = std::fs::read_to_string(root().join("docs/results/durations.toml"))
        .expect("docs/results/durations.toml");
    toml::from_str(&text).expect("docs/results/durations.toml parses")
}

#[test]
fn the_readme_and_every_guide_match_the_code() {
    let files = doc_files();
    assert!(files.len() >= 8, "README.md and the guides: {files:?}");
    let mut errors = Vec::new();
    let mut commands = 0;
    let mut keys = 0;
    for f in &files {
        let text = std::fs::read_to_string(f).unwrap();
        errors.extend(check_file(f, &text));
        let s = snippets(&text);
        commands += s
            .commands
            .iter()
            .filter(|c| check_command(c).unwrap_or(true))
            .count();
        keys += s
            .inline
            .iter()
            .filter(|i| check_config_key(i).is_some())
            .count();
    }
    let readme = std::fs::read_to_string(root().join("README.md")).unwrap();
    errors.extend(check_durations(&snippets(&readme).prose, &durations_file()));
    assert!(
        errors.is_empty(),
        "{} problems:\n{}",
        errors.len(),
        errors.join("\n")
    );
    // The checks saw the docs' content, not an empty extraction.
    assert!(commands >= 50, "only {commands} command lines were checked");
    assert!(keys >= 20, "only {keys} config keys were checked");
}

#[test]
fn a_misspelt_flag_subcommand_or_missing_argument_fails() {
    for bad in [
        "terl status --jsno",
        "terl stauts",
        "terl eval --json",
        "./deploy/local-cluster.sh --config deploy/configs/mt10.toml --actor 2",
        "terl-learner --config run.toml --run-id r1 --num-actor 2",
        "terl-actor --config run.toml --run-id r1",
        "TERL_TOKEN=x terl status --adr 127.0.0.1:1",
        "./deploy/experiments/run.sh mt10 --seed 3",
        "./deploy/no-such-script.sh",
        "terl status … ",
    ] {
        assert!(check_command(bad).is_err(), "{bad:?} was accepted");
    }
    for good in [
        "terl status --json",
        "terl bench sac --hidden 256 --batch 256 --threads 2 # a comment",
        "./deploy/local-cluster.sh --config deploy/configs/mt10-workstation.toml --actors 2",
        "TERL_TOKEN=x terl status --addr 127.0.0.1:1 | head -1",
        "./deploy/experiments/run.sh mt10 --seeds \"4 5\" --no-build",
    ] {
        assert_eq!(check_command(good), Ok(true), "{good:?}");
    }
    assert_eq!(check_command("kubectl get pods"), Ok(false));
}

#[test]
fn a_misspelt_key_bad_value_or_block_fails() {
    for (section, key) in [
        ("train", "total_env_steps"),
        ("sac", "gamma"),
        ("ptr", "success_threshold"),
        ("tep", "f_hidden"),
        ("guidance", "sigma"),
        ("cluster", "transport"),
        ("cluster.zenoh", "mode"),
    ] {
        let good = format!("[{section}] {key}");
        assert_eq!(check_config_key(&good), Some(Ok(())), "{good:?}");
        let bad = format!("[{section}] {key}_zz");
        assert!(
            matches!(check_config_key(&bad), Some(Err(_))),
            "{bad:?} was accepted: [{section}] does not refuse unknown keys"
        );
    }
    assert!(matches!(
        check_config_key("[cluster] transport = \"pigeon\""),
        Some(Err(_))
    ));
    assert_eq!(
        check_config_key("[cluster] transport = \"zenoh\""),
        Some(Ok(()))
    );
    assert_eq!(check_config_key("not a key"), None);
    assert!(check_toml_block("[cluster]\ntransprt = \"zenoh\"\n").is_err());
    assert!(check_toml_block("[cluster]\ntransport = \"zenoh\"\n").is_ok());
}

#[test]
fn a_missing_path_link_or_unrecorded_duration_fails() {
    assert!(matches!(
        check_path("deploy/configs/mt10.toml"),
        Some(Ok(()))
    ));
    assert!(matches!(
        check_path("deploy/configs/mt11.toml"),
        Some(Err(_))
    ));
    assert_eq!(check_path("runs/<id>/cluster.txt"), None);
    let readme = root().join("README.md");
    assert!(matches!(
        check_link(&readme, "docs/cluster.md"),
        Some(Ok(()))
    ));
    assert!(matches!(
        check_link(&readme, "docs/clustr.md"),
        Some(Err(_))
    ));
    let file = durations_file();
    assert!(!file.duration.is_empty());
    let quoted = &file.duration[0].quoted;
    assert!(check_durations(&format!("setup takes {quoted} here"), &file).is_empty());
    assert_eq!(
        check_durations("the build takes about 97 minutes", &file).len(),
        1,
        "an unrecorded duration was accepted"
    );
    assert_eq!(
        durations("in 35–73 minutes, or about two days."),
        ["35–73 minutes", "about two days"]
    );
}
