//! The guide (`docs/guide`, an mdBook) as a user reads it: each terminal session in it (a
//! ```` ```console ```` block: `$ command`, then what it prints) runs against a real `ussd` on a
//! simulated bus of this test's own name and prints what the guide says (trycmd: `[..]` is a
//! part that differs from run to run, `...` lines left out); every link resolves, to a file and
//! to a heading; the troubleshooting chapter explains every warning and error `ussd` can log;
//! and `mdbook build` makes the book (CI installs mdbook: `USS_REQUIRE_MDBOOK=1`).
#![allow(clippy::unwrap_used)]

use pulldown_cmark::{Event, Parser, Tag, TagEnd};
use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};
use std::process::Command;
use uss_integration_tests::{Ussd, binary, root};

fn guide() -> PathBuf {
    root().join("docs/guide")
}

/// The chapters in `src/`, by file name.
fn chapters() -> BTreeMap<String, String> {
    std::fs::read_dir(guide().join("src"))
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|e| e == "md"))
        .map(|p| {
            let name = p.file_name().unwrap().to_str().unwrap().to_owned();
            (name, std::fs::read_to_string(&p).unwrap())
        })
        .collect()
}

/// Whether a chapter has a terminal session that talks to ussd (`$ ussctl ...` other than its
/// help): those get a ussd of their own.
fn needs_ussd(text: &str) -> bool {
    text.lines().any(|l| {
        l.starts_with("$ ussctl ")
            && !l.contains("--help")
            && !l.contains(" schema")
            && !l.contains(" completions")
    })
}

#[test]
fn every_terminal_session_of_the_guide_prints_what_it_says() {
    // The sessions run in a directory of their own, with the guide's example files: what a
    // command writes (a backup) stays out of the repository.
    let work = std::env::temp_dir().join(format!("uss-guide-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&work);
    std::fs::create_dir_all(work.join("examples")).unwrap();
    for e in std::fs::read_dir(guide().join("examples")).unwrap() {
        let path = e.unwrap().path();
        std::fs::copy(&path, work.join("examples").join(path.file_name().unwrap())).unwrap();
    }
    // Built before the sessions leave the workspace (binary() runs cargo there).
    let bins = [
        ("ussctl", binary("ussctl", "ussctl")),
        ("ussd", binary("uss-master", "ussd")),
        ("uss-sim", binary("uss-drive-sim", "uss-sim")),
    ];
    std::env::set_current_dir(&work).unwrap();
    let mut ran = 0;
    for (name, text) in chapters() {
        if !text.contains("```console") {
            continue;
        }
        // A drive of the guide's bus trips (F0072) when ussd sends it nothing for 100 ms. A
        // kernel without preemption (PREEMPT_NONE, as on CI's virtual machines) can hold even
        // ussd's real-time thread that long while processes start and end around it: the
        // drives then truly trip, the session rightly differs, and it runs once more on a
        // fresh bus. A session that differs without a trip fails at once.
        match session(&name, &text, &bins) {
            Ok(()) => {}
            Err(Failed { tripped: true, .. }) => {
                eprintln!(
                    "{name}: ussd was held past the drives' 100 ms telegram monitoring and they \
                     tripped (see ussd's log above); running the chapter once more"
                );
                if let Err(again) = session(&name, &text, &bins) {
                    std::panic::resume_unwind(again.panic);
                }
            }
            Err(f) => std::panic::resume_unwind(f.panic),
        }
        ran += 1;
    }
    assert!(ran >= 3, "the guide's terminal sessions: {ran} chapters");
    let _ = std::fs::remove_dir_all(&work);
}

/// A chapter whose sessions differed: the test's panic, and whether ussd's log shows its
/// drives tripped meanwhile.
struct Failed {
    panic: Box<dyn std::any::Any + Send>,
    tripped: bool,
}

/// Runs one chapter's terminal sessions. Each chapter gets a fresh bus: the simulated bus ussd
/// runs with no configuration (`master/src/config/mod.rs`, `EMBEDDED_DEFAULT`), under this test's
/// own bus name.
fn session(name: &str, text: &str, bins: &[(&str, PathBuf)]) -> Result<(), Failed> {
    let monitored = "sim = { p2014 = 100 }";
    let ussd = needs_ussd(text).then(|| {
        Ussd::start(
            "",
            &[
                (1, monitored),
                (2, monitored),
                (3, "pkw = 127\nsim = { p2014 = 100 }"),
                (4, monitored),
            ],
        )
    });
    // A session begins once ussd knows every drive's reference, as it does moments after its
    // start: before, `status` rightly shows NaN Hz.
    if let Some(u) = &ussd {
        let bus = u.bus_named("");
        for a in 1..=4 {
            bus.watch(uss_integration_tests::addr(a))
                .unwrap()
                .wait_for_reference(std::time::Duration::from_secs(20))
                .unwrap();
        }
    }
    // A line the chapter starts in a terminal of its own (`uss-sim --pty --link line ...`, for
    // the scan) runs as written, in the sessions' directory, while they run.
    // (Killed with SIGKILL after the chapter, it leaves its link: removed here.)
    let _ = std::fs::remove_file("line");
    let _line = text
        .lines()
        .find(|l| l.starts_with("uss-sim --pty --link ") && text.contains("$ ussctl scan line"))
        .map(|l| {
            let uss_sim = &bins.iter().find(|(n, _)| *n == "uss-sim").unwrap().1;
            let mut command = Command::new(uss_sim);
            command.args(l.split_whitespace().skip(1));
            let mut sim = uss_integration_tests::ChildProc::spawn(l.to_owned(), command);
            sim.says("link line -> ");
            sim
        });
    let cases = trycmd::TestCases::new();
    cases
        .register_bins(bins.iter().map(|(n, p)| (*n, p.clone())))
        .env(
            "USS_BUS",
            ussd.as_ref().map_or("guide-nobody", |u| u.bus.as_str()),
        )
        .timeout(std::time::Duration::from_secs(60))
        .case(guide().join("src").join(name));
    if let Some(u) = &ussd {
        cases.insert_var("[BUS]", u.bus.clone()).unwrap();
    }
    std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| drop(cases))).map_err(|panic| {
        let tripped = ussd.as_ref().is_some_and(|u| {
            let log = u.log();
            let tripped = log.contains("the drive tripped");
            if tripped {
                eprintln!("ussd's log:\n{log}");
            }
            tripped
        });
        Failed { panic, tripped }
    })
}

/// A heading's id as mdBook makes it (and GitHub, for these texts): lower case, spaces to `-`,
/// other punctuation dropped.
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

/// Every heading's id in a Markdown text.
fn anchors(text: &str) -> BTreeSet<String> {
    let mut out = BTreeSet::new();
    let mut heading: Option<String> = None;
    for event in Parser::new(text) {
        match event {
            Event::Start(Tag::Heading { .. }) => heading = Some(String::new()),
            Event::Text(t) | Event::Code(t) => {
                if let Some(h) = heading.as_mut() {
                    h.push_str(&t);
                }
            }
            Event::End(TagEnd::Heading(_)) => {
                out.insert(anchor(&heading.take().unwrap()));
            }
            _ => {}
        }
    }
    out
}

/// Every link and image target of a Markdown text.
fn links(text: &str) -> Vec<String> {
    Parser::new(text)
        .filter_map(|event| match event {
            Event::Start(Tag::Link { dest_url, .. } | Tag::Image { dest_url, .. }) => {
                Some(dest_url.to_string())
            }
            _ => None,
        })
        .collect()
}

/// The broken links of `file` (a Markdown file of the repository): a relative target that does
/// not exist, or a `#heading` its Markdown file does not have.
fn broken_links(file: &Path) -> Vec<String> {
    let text = std::fs::read_to_string(file).unwrap();
    let dir = file.parent().unwrap();
    let mut broken = Vec::new();
    for target in links(&text) {
        if target.contains("://") || target.starts_with("mailto:") {
            continue;
        }
        let (path, fragment) = match target.split_once('#') {
            Some((p, f)) => (p, Some(f)),
            None => (target.as_str(), None),
        };
        let resolved = if path.is_empty() {
            file.to_path_buf()
        } else {
            dir.join(path)
        };
        if !resolved.exists() {
            broken.push(format!("{}: {target}: no such file", file.display()));
            continue;
        }
        if let Some(fragment) = fragment {
            let is_markdown = resolved.extension().is_some_and(|e| e == "md");
            if is_markdown
                && !anchors(&std::fs::read_to_string(&resolved).unwrap()).contains(fragment)
            {
                broken.push(format!("{}: {target}: no such heading", file.display()));
            }
        }
    }
    broken
}

#[test]
fn every_link_of_the_guide_and_the_readme_resolves() {
    let mut files: Vec<PathBuf> = chapters()
        .keys()
        .map(|n| guide().join("src").join(n))
        .collect();
    files.extend(
        [
            "README.md",
            "docs/ARCHITECTURE.md",
            "docs/USS.md",
            "docs/SAFETY.md",
        ]
        .map(|f| root().join(f)),
    );
    let broken: Vec<String> = files.iter().flat_map(|f| broken_links(f)).collect();
    assert!(broken.is_empty(), "{}", broken.join("\n"));
    // The summary names every chapter, and every chapter is in it.
    let summary = std::fs::read_to_string(guide().join("src/SUMMARY.md")).unwrap();
    let listed: BTreeSet<String> = links(&summary).into_iter().collect();
    let present: BTreeSet<String> = chapters()
        .into_keys()
        .filter(|n| n != "SUMMARY.md")
        .collect();
    assert_eq!(listed, present, "SUMMARY.md and the chapters in src/");
}

/// The format strings of every `tracing::warn!` and `tracing::error!` under `dir`, outside
/// tests.
fn logged(dir: &Path, out: &mut Vec<(PathBuf, String)>) {
    for e in std::fs::read_dir(dir).unwrap() {
        let path = e.unwrap().path();
        if path.is_dir() {
            if path.file_name().is_some_and(|n| n != "tests") {
                logged(&path, out);
            }
            continue;
        }
        if path.extension().is_none_or(|e| e != "rs")
            || path.file_name().is_some_and(|n| n == "tests.rs")
        {
            continue;
        }
        let text = std::fs::read_to_string(&path).unwrap();
        let text = text.split("#[cfg(test)]").next().unwrap();
        for macro_ in ["tracing::warn!(", "tracing::error!("] {
            for (at, _) in text.match_indices(macro_) {
                let rest = &text[at..];
                let Some(open) = rest.find('"') else { continue };
                let mut literal = String::new();
                let mut chars = rest[open + 1..].chars();
                while let Some(c) = chars.next() {
                    match c {
                        '"' => break,
                        '\\' => {
                            // A line continuation drops the newline and the indent after it.
                            match chars.next() {
                                Some('\n') => {
                                    let next: String =
                                        chars.clone().take_while(|c| c.is_whitespace()).collect();
                                    for _ in 0..next.chars().count() {
                                        chars.next();
                                    }
                                }
                                Some(other) => literal.push(other),
                                None => {}
                            }
                        }
                        c => literal.push(c),
                    }
                }
                out.push((path.clone(), literal));
            }
        }
    }
}

/// The words of a format string that stay the same in every line it logs: its longest piece
/// between two `{...}`, if it says anything (at least 12 characters).
fn fixed_words(format: &str) -> Option<String> {
    let mut pieces = Vec::new();
    let mut piece = String::new();
    let mut depth = 0;
    for c in format.chars() {
        match c {
            '{' => {
                depth += 1;
                pieces.push(std::mem::take(&mut piece));
            }
            '}' => depth -= 1,
            c if depth == 0 => piece.push(c),
            _ => {}
        }
    }
    pieces.push(piece);
    pieces
        .into_iter()
        .map(|p| {
            p.trim()
                .trim_matches(|c: char| c == ':' || c == ';')
                .trim()
                .to_owned()
        })
        .filter(|p| p.chars().count() >= 12)
        .max_by_key(|p| p.chars().count())
}

#[test]
fn the_troubleshooting_chapter_explains_every_warning_and_error_ussd_logs() {
    let chapter = std::fs::read_to_string(guide().join("src/troubleshooting.md")).unwrap();
    let mut found = Vec::new();
    for dir in ["master/src", "engine/src", "serial/src"] {
        logged(&root().join(dir), &mut found);
    }
    assert!(found.len() >= 25, "{found:?}");
    let missing: Vec<String> = found
        .iter()
        .filter_map(|(path, format)| {
            let words = fixed_words(format)?;
            (!chapter.contains(&words)).then(|| format!("{}: {words:?}", path.display()))
        })
        .collect();
    assert!(
        missing.is_empty(),
        "logged by ussd, not in docs/guide/src/troubleshooting.md:\n{}",
        missing.join("\n")
    );
}

/// `mdbook`, where CI installs it or on PATH.
fn mdbook() -> Option<PathBuf> {
    let home = std::env::var_os("HOME").map(PathBuf::from);
    let candidates = home.iter().map(|h| h.join(".cargo/bin/mdbook")).chain(
        std::env::var_os("PATH").into_iter().flat_map(|p| {
            std::env::split_paths(&p)
                .map(|d| d.join("mdbook"))
                .collect::<Vec<_>>()
        }),
    );
    candidates.into_iter().find(|p| p.is_file())
}

#[test]
fn mdbook_builds_the_guide() {
    let Some(mdbook) = mdbook() else {
        assert!(
            std::env::var_os("USS_REQUIRE_MDBOOK").is_none(),
            "USS_REQUIRE_MDBOOK is set and mdbook is not installed"
        );
        println!("guide: mdbook not installed: not built (cargo install mdbook)");
        return;
    };
    let out_dir = std::env::temp_dir().join(format!("uss-guide-html-{}", std::process::id()));
    let out = Command::new(mdbook)
        .arg("build")
        .arg(guide())
        .arg("--dest-dir")
        .arg(&out_dir)
        .output()
        .unwrap();
    let said = format!(
        "{}{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(out.status.success(), "{said}");
    assert!(!said.contains("WARN") && !said.contains("ERROR"), "{said}");
    for page in [
        "index.html",
        "troubleshooting.html",
        "safety.html",
        "print.html",
    ] {
        assert!(out_dir.join(page).is_file(), "{page}: {said}");
    }
    let _ = std::fs::remove_dir_all(&out_dir);
}

/// Issue 47, item 3: troubleshooting named keys that do not exist (`rt_priority`, `rt_cpu`,
/// `require_rt`). Every snake-case word the guide or the README writes in backticks on a line
/// about the configuration (configuration, config, a `.toml`, `[[bus`, a key, a unit) is a key
/// that ussd's configuration takes: the keys of `ussd --check-config`'s effective configuration
/// of a file that sets every optional one.
#[test]
fn every_configuration_key_the_guide_names_is_one_ussd_takes() {
    let file = std::env::temp_dir().join(format!("uss-guide-keys-{}.toml", std::process::id()));
    std::fs::write(
        &file,
        "access_group = \"root\"\n\n[[bus]]\nname = \"keys\"\ndevice = \"sim\"\n\
         rx_latency_ms = 1.0\nseed = 7\ncpu = 0\n\n[[bus.drive]]\naddress = 1\n\
         family = \"g120\"\npole_pairs = 2\nwritable = [\"p1120\"]\nsim = { delay = 2 }\n",
    )
    .unwrap();
    let out = Command::new(binary("uss-master", "ussd"))
        .arg("--check-config")
        .arg(&file)
        .output()
        .unwrap();
    let _ = std::fs::remove_file(&file);
    let effective = String::from_utf8_lossy(&out.stdout).into_owned();
    assert!(out.status.success(), "{effective}");
    let mut keys: BTreeSet<String> = effective
        .lines()
        .filter_map(|l| l.split_once(" = ").map(|(k, _)| k.trim().to_owned()))
        .filter(|k| !k.starts_with('#'))
        .collect();
    // Its tables.
    keys.extend(["bus", "drive", "sim"].map(str::to_owned));
    assert!(
        keys.contains("cpu") && keys.contains("pole_pairs"),
        "{keys:?}"
    );
    let about_config = ["configuration", "config", ".toml", "[[bus", " key", " unit"];
    let mut texts: Vec<(String, String)> = chapters().into_iter().collect();
    texts.push((
        "README.md".to_owned(),
        std::fs::read_to_string(root().join("README.md")).unwrap(),
    ));
    let mut unknown = Vec::new();
    for (name, text) in &texts {
        for (n, line) in text.lines().enumerate() {
            let lower = line.to_lowercase();
            if !about_config.iter().any(|w| lower.contains(w)) {
                continue;
            }
            for word in line.split('`').skip(1).step_by(2) {
                let snake = word.contains('_')
                    && word
                        .chars()
                        .all(|c| c.is_ascii_lowercase() || c.is_ascii_digit() || c == '_')
                    && word.starts_with(|c: char| c.is_ascii_lowercase());
                if snake && !keys.contains(word) {
                    unknown.push(format!("{name}:{}: `{word}`", n + 1));
                }
            }
        }
    }
    assert!(
        unknown.is_empty(),
        "named beside the configuration, not a key ussd takes ({keys:?}):\n{}",
        unknown.join("\n")
    );
}
