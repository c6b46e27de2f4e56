//! The documentation's links, checked without the network. In README.md, DESIGN.md, docs/**/*.md and
//! every README.md of the workspace, each relative link must point at a file or directory that
//! exists, each `#anchor` (in the same file or in `file.md#anchor`) at a heading of its target, named
//! by GitHub's rules, and each http(s) link must be well formed (it is not fetched). README.md stays an
//! entry a newcomer reads in minutes: at most 260 lines.

use std::collections::{BTreeSet, HashMap};
use std::fs;
use std::path::{Component, Path, PathBuf};

/// The longest README.md may grow.
const README_MAX_LINES: usize = 260;

fn repository() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .parent()
        .expect("tests/ sits in the repository")
        .to_path_buf()
}

/// A link as written: its destination and the 1-based line the destination is on.
#[derive(Debug, PartialEq)]
struct Link {
    line: usize,
    destination: String,
}

/// The text with what Markdown does not read as links blanked out: fenced code blocks and inline
/// code spans become spaces, newlines are kept, so offsets and line numbers stay those of the file.
fn without_code(text: &str) -> Vec<char> {
    let mut out: Vec<char> = Vec::with_capacity(text.len());
    let mut fence: Option<(char, usize)> = None;
    for line in text.split_inclusive('\n') {
        let trimmed = line.trim_start_matches(' ');
        let indent = line.len() - trimmed.len();
        let marker = trimmed.chars().next().filter(|c| *c == '`' || *c == '~');
        let run = marker.map_or(0, |m| trimmed.chars().take_while(|c| *c == m).count());
        let is_fence = indent <= 3 && run >= 3;
        // A fence closes on a line of at least as many of its own marks and nothing else.
        let closes = |(m, n): (char, usize)| {
            is_fence && marker == Some(m) && run >= n && trimmed[run..].trim().is_empty()
        };
        match fence {
            None if is_fence => fence = marker.map(|m| (m, run)),
            Some(open) if closes(open) => fence = None,
            _ => {}
        }
        let blank = fence.is_some() || is_fence;
        out.extend(
            line.chars()
                .map(|c| if blank && c != '\n' { ' ' } else { c }),
        );
    }
    blank_code_spans(&mut out);
    out
}

/// Blanks inline code spans: a run of n backticks up to the next run of exactly n, within one
/// paragraph (a span never crosses a blank line). An unmatched run stays as it is.
fn blank_code_spans(text: &mut [char]) {
    let mut i = 0;
    while i < text.len() {
        if text[i] != '`' {
            i += 1;
            continue;
        }
        let open = run_length(text, i, '`');
        let mut j = i + open;
        let mut close = None;
        while j < text.len() {
            if text[j] == '`' {
                let n = run_length(text, j, '`');
                if n == open {
                    close = Some(j);
                    break;
                }
                j += n;
            } else if text[j] == '\n' && paragraph_ends(text, j) {
                break;
            } else {
                j += 1;
            }
        }
        match close {
            Some(c) => {
                for ch in &mut text[i..c + open] {
                    if *ch != '\n' {
                        *ch = ' ';
                    }
                }
                i = c + open;
            }
            None => i += open,
        }
    }
}

fn run_length(text: &[char], from: usize, c: char) -> usize {
    text[from..].iter().take_while(|&&x| x == c).count()
}

/// Whether the newline at `at` is followed by a blank line.
fn paragraph_ends(text: &[char], at: usize) -> bool {
    let rest = text[at + 1..].iter().take_while(|&&c| c != '\n');
    let (mut all_blank, mut length) = (true, 0);
    for c in rest {
        length += 1;
        all_blank &= c.is_whitespace();
    }
    all_blank && at + 1 + length < text.len()
}

fn line_of(text: &[char], at: usize) -> usize {
    1 + text[..at].iter().filter(|&&c| c == '\n').count()
}

/// Every inline link and image `[text](destination "title")`, every autolink `<https://...>` and
/// every reference definition `[name]: destination`, outside code.
fn links(text: &str) -> Vec<Link> {
    let chars = without_code(text);
    let mut found = Vec::new();
    let mut i = 0;
    while i < chars.len() {
        match chars[i] {
            '\\' => i += 1,
            '[' => {
                if let Some(close) = matching_bracket(&chars, i) {
                    if chars.get(close + 1) == Some(&'(') {
                        if let Some(destination) = destination(&chars, close + 2) {
                            found.push(Link {
                                line: line_of(&chars, close + 1),
                                destination,
                            });
                        }
                    } else if chars.get(close + 1) == Some(&':') && starts_line(&chars, i) {
                        let rest: String = chars[close + 2..]
                            .iter()
                            .take_while(|&&c| c != '\n')
                            .collect();
                        if let Some(d) = rest.split_whitespace().next() {
                            found.push(Link {
                                line: line_of(&chars, i),
                                destination: d.trim_matches(['<', '>']).to_string(),
                            });
                        }
                    }
                }
            }
            '<' => {
                let rest: String = chars[i + 1..]
                    .iter()
                    .take_while(|&&c| c != '>' && c != '\n' && c != ' ')
                    .collect();
                if (rest.starts_with("http://") || rest.starts_with("https://"))
                    && chars.get(i + 1 + rest.chars().count()) == Some(&'>')
                {
                    found.push(Link {
                        line: line_of(&chars, i),
                        destination: rest,
                    });
                }
            }
            _ => {}
        }
        i += 1;
    }
    found
}

/// Only blanks before a `[` at `at` on its line (a reference definition starts a line).
fn starts_line(text: &[char], at: usize) -> bool {
    text[..at]
        .iter()
        .rev()
        .take_while(|&&c| c != '\n')
        .all(|c| *c == ' ')
}

/// The `]` closing the `[` at `open`, brackets nested, within one paragraph.
fn matching_bracket(text: &[char], open: usize) -> Option<usize> {
    let mut depth = 0usize;
    let mut i = open;
    while i < text.len() {
        match text[i] {
            '\\' => i += 1,
            '[' => depth += 1,
            ']' => {
                depth -= 1;
                if depth == 0 {
                    return Some(i);
                }
            }
            '\n' if paragraph_ends(text, i) => return None,
            _ => {}
        }
        i += 1;
    }
    None
}

/// The destination of an inline link whose `(` ends just before `from`: `<...>`, or up to the first
/// space (a title follows) or the `)` closing it, parentheses nested.
fn destination(text: &[char], from: usize) -> Option<String> {
    let mut i = from;
    while i < text.len() && (text[i] == ' ' || text[i] == '\n') {
        i += 1;
    }
    if text.get(i) == Some(&'<') {
        let end = text[i + 1..].iter().position(|&c| c == '>' || c == '\n')?;
        return Some(text[i + 1..i + 1 + end].iter().collect());
    }
    let mut depth = 0usize;
    let start = i;
    while i < text.len() {
        match text[i] {
            '\\' => i += 1,
            '(' => depth += 1,
            ')' if depth == 0 => break,
            ')' => depth -= 1,
            c if c.is_whitespace() => break,
            _ => {}
        }
        i += 1;
    }
    (i < text.len()).then(|| text[start..i].iter().collect())
}

/// GitHub's anchor for a heading's text: the text as rendered (link syntax and inline code
/// marks gone), lower-cased, every character that is not a letter, a digit, a mark, '-' or '_'
/// removed, and each space made a '-'.
fn slug(heading: &str) -> String {
    let mut rendered = String::new();
    let chars: Vec<char> = heading.chars().collect();
    let mut i = 0;
    while i < chars.len() {
        // `[text](url)` renders as its text.
        if chars[i] == '['
            && let Some(close) = matching_bracket(&chars, i)
            && chars.get(close + 1) == Some(&'(')
            && let Some(end) = chars[close + 2..].iter().position(|&c| c == ')')
        {
            rendered.extend(&chars[i + 1..close]);
            i = close + 2 + end + 1;
            continue;
        }
        rendered.push(chars[i]);
        i += 1;
    }
    rendered
        .trim()
        .to_lowercase()
        .chars()
        .filter_map(|c| match c {
            ' ' => Some('-'),
            '-' | '_' => Some(c),
            c if c.is_alphanumeric() => Some(c),
            _ => None,
        })
        .collect()
}

/// The anchors of a Markdown file's ATX headings outside code, as GitHub names them: a repeated
/// slug takes `-1`, `-2`, ... in order.
fn anchors(text: &str) -> BTreeSet<String> {
    let chars: String = without_code(text).into_iter().collect();
    let mut seen: HashMap<String, usize> = HashMap::new();
    let mut out = BTreeSet::new();
    for line in chars.lines() {
        let trimmed = line.trim_start_matches(' ');
        if line.len() - trimmed.len() > 3 {
            continue;
        }
        let level = trimmed.chars().take_while(|&c| c == '#').count();
        if level == 0 || level > 6 {
            continue;
        }
        let rest = &trimmed[level..];
        if !(rest.is_empty() || rest.starts_with([' ', '\t'])) {
            continue;
        }
        // The heading's own text, in the original (code spans are blanked in `chars`).
        let original = text.lines().nth(out_line(&chars, line)).unwrap_or(line);
        let content = original.trim_start_matches(' ')[level..].trim();
        let content = content.trim_end_matches('#').trim_end();
        let base = slug(content);
        let n = seen.entry(base.clone()).or_insert(0);
        out.insert(if *n == 0 { base } else { format!("{base}-{n}") });
        *n += 1;
    }
    out
}

/// The 0-based index of `line` (a slice of `text`) among `text`'s lines.
fn out_line(text: &str, line: &str) -> usize {
    let offset = line.as_ptr() as usize - text.as_ptr() as usize;
    text[..offset].matches('\n').count()
}

/// Decodes `%XX` escapes of a link's path.
fn percent_decoded(path: &str) -> String {
    let bytes = path.as_bytes();
    let mut out = Vec::with_capacity(bytes.len());
    let mut i = 0;
    while i < bytes.len() {
        if bytes[i] == b'%'
            && let Some(hex) = path.get(i + 1..i + 3)
            && let Ok(b) = u8::from_str_radix(hex, 16)
        {
            out.push(b);
            i += 3;
            continue;
        }
        out.push(bytes[i]);
        i += 1;
    }
    String::from_utf8_lossy(&out).into_owned()
}

/// Whether an http(s) link is well formed: the scheme, a host of letters, digits, dots and
/// hyphens (with an optional port), nothing a URL cannot hold.
fn well_formed_web_link(url: &str) -> bool {
    let Some(rest) = url
        .strip_prefix("https://")
        .or_else(|| url.strip_prefix("http://"))
    else {
        return false;
    };
    let authority = rest.split(['/', '?', '#']).next().unwrap_or("");
    let host = match authority.rsplit_once(':') {
        Some((host, port)) if !port.is_empty() && port.chars().all(|c| c.is_ascii_digit()) => host,
        Some(_) => return false,
        None => authority,
    };
    !host.is_empty()
        && host
            .split('.')
            .all(|label| !label.is_empty() && !label.starts_with('-') && !label.ends_with('-'))
        && (host.contains('.') || host == "localhost")
        && host
            .chars()
            .all(|c| c.is_ascii_alphanumeric() || c == '.' || c == '-')
        && !url
            .chars()
            .any(|c| c.is_whitespace() || c.is_control() || "<>\"`{}|\\^".contains(c))
}

/// `path` with `.` and `..` resolved lexically; None when it climbs above its start.
fn normalised(path: &Path) -> Option<PathBuf> {
    let mut out = PathBuf::new();
    for part in path.components() {
        match part {
            Component::CurDir => {}
            Component::ParentDir => {
                if !out.pop() {
                    return None;
                }
            }
            other => out.push(other),
        }
    }
    Some(out)
}

/// Checks every link of the Markdown files `files` (relative to `root`); returns one message per
/// broken link, `FILE:LINE: what is wrong`.
fn check(root: &Path, files: &[PathBuf]) -> Vec<String> {
    let mut texts: HashMap<PathBuf, String> = HashMap::new();
    let mut read = |path: &Path| -> Option<String> {
        if let Some(t) = texts.get(path) {
            return Some(t.clone());
        }
        let t = fs::read_to_string(root.join(path)).ok()?;
        texts.insert(path.to_path_buf(), t.clone());
        Some(t)
    };
    let mut problems = Vec::new();
    for file in files {
        let text = read(file).unwrap_or_else(|| panic!("cannot read {}", file.display()));
        for link in links(&text) {
            let at = format!("{}:{}", file.display(), link.line);
            let d = link.destination.as_str();
            if d.is_empty() {
                problems.push(format!("{at}: a link with no destination"));
                continue;
            }
            if d.starts_with("http://") || d.starts_with("https://") {
                if !well_formed_web_link(d) {
                    problems.push(format!("{at}: `{d}` is not a well-formed web link"));
                }
                continue;
            }
            if let Some(address) = d.strip_prefix("mailto:") {
                if !address.contains('@') {
                    problems.push(format!("{at}: `{d}` is not an e-mail address"));
                }
                continue;
            }
            let scheme = d.split_once(':').map(|(s, _)| s).unwrap_or("");
            if !scheme.is_empty()
                && scheme
                    .chars()
                    .all(|c| c.is_ascii_alphanumeric() || "+.-".contains(c))
                && !scheme.contains('/')
            {
                problems.push(format!(
                    "{at}: `{d}`: only http(s) and mailto links may leave the repository"
                ));
                continue;
            }
            let (path, anchor) = match d.split_once('#') {
                Some((p, a)) => (p, Some(a)),
                None => (d, None),
            };
            let target = if path.is_empty() {
                Some(file.clone())
            } else {
                let path = percent_decoded(path);
                let joined = match path.strip_prefix('/') {
                    Some(from_root) => PathBuf::from(from_root),
                    None => file.parent().unwrap_or(Path::new("")).join(&path),
                };
                normalised(&joined)
            };
            let Some(target) = target else {
                problems.push(format!("{at}: `{d}` points outside the repository"));
                continue;
            };
            if !root.join(&target).exists() {
                problems.push(format!(
                    "{at}: `{d}`: no such file or directory ({})",
                    target.display()
                ));
                continue;
            }
            let Some(anchor) = anchor else { continue };
            if target.extension().is_some_and(|e| e == "md") {
                let headings = anchors(&read(&target).unwrap_or_default());
                if !headings.contains(&percent_decoded(anchor)) {
                    problems.push(format!(
                        "{at}: `{d}`: {} has no heading `#{anchor}`",
                        target.display()
                    ));
                }
            } else if !is_line_anchor(anchor) {
                problems.push(format!(
                    "{at}: `{d}`: an anchor into {}, which is not Markdown",
                    target.display()
                ));
            }
        }
    }
    problems
}

/// GitHub's anchors into a source file's lines: `L12` or `L12-L20`.
fn is_line_anchor(anchor: &str) -> bool {
    let line = |s: &str| {
        s.strip_prefix('L')
            .is_some_and(|n| !n.is_empty() && n.chars().all(|c| c.is_ascii_digit()))
    };
    match anchor.split_once('-') {
        Some((a, b)) => line(a) && line(b),
        None => line(anchor),
    }
}

/// The documentation: README.md, DESIGN.md, every Markdown file under docs/, and every README.md
/// in the workspace (build output, run output and hidden directories left out), relative to `root`.
fn documentation(root: &Path) -> Vec<PathBuf> {
    fn walk(root: &Path, dir: &Path, docs: bool, out: &mut Vec<PathBuf>) {
        let mut entries: Vec<_> = fs::read_dir(root.join(dir))
            .unwrap_or_else(|e| panic!("{}: {e}", root.join(dir).display()))
            .map(|e| e.unwrap())
            .collect();
        entries.sort_by_key(|e| e.file_name());
        for entry in entries {
            let name = entry.file_name().to_string_lossy().into_owned();
            let path = dir.join(&name);
            let kind = entry.file_type().unwrap();
            if kind.is_dir() {
                if !(name.starts_with('.') || name == "target" || name == "out") {
                    walk(root, &path, docs || path == Path::new("docs"), out);
                }
            } else if name == "README.md" || (docs && name.ends_with(".md")) {
                out.push(path);
            }
        }
    }
    let mut files = vec![PathBuf::from("DESIGN.md")];
    walk(root, Path::new(""), false, &mut files);
    files.sort();
    files.dedup();
    files
}

#[test]
fn every_link_of_the_documentation_resolves() {
    let root = repository();
    let files = documentation(&root);
    for must in ["README.md", "DESIGN.md", "docs/README.md"] {
        assert!(
            files.contains(&PathBuf::from(must)),
            "{must} is not among the documentation checked: {files:?}"
        );
    }
    let problems = check(&root, &files);
    let count: usize = files
        .iter()
        .map(|f| links(&fs::read_to_string(root.join(f)).unwrap()).len())
        .sum();
    println!("{count} links in {} files checked", files.len());
    assert!(
        problems.is_empty(),
        "{} broken link(s) in the documentation:\n{}",
        problems.len(),
        problems.join("\n")
    );
}

#[test]
fn the_readme_stays_short() {
    let text = fs::read_to_string(repository().join("README.md")).unwrap();
    let lines = text.lines().count();
    assert!(
        lines <= README_MAX_LINES,
        "README.md has {lines} lines, more than {README_MAX_LINES}: move the detail to docs/"
    );
}

#[test]
fn headings_are_named_as_github_names_them() {
    assert_eq!(
        slug("The vehicle's safety layer"),
        "the-vehicles-safety-layer"
    );
    assert_eq!(
        slug("Health: heartbeats, stuck services, `status`"),
        "health-heartbeats-stuck-services-status"
    );
    assert_eq!(
        slug("Embedded, not `iox2 link tunnel zenoh`"),
        "embedded-not-iox2-link-tunnel-zenoh"
    );
    assert_eq!(slug("Step two over 12 seeds"), "step-two-over-12-seeds");
    assert_eq!(slug("A — B"), "a--b");
    assert_eq!(slug("max_action_change (0.05)"), "max_action_change-005");
    assert_eq!(slug("Über die Größe"), "über-die-größe");
    assert_eq!(
        slug("See [the design](DESIGN.md) first"),
        "see-the-design-first"
    );
    let text = "# Title\n\n## Notes\n\n```sh\n# not a heading\n```\n\n### Notes ###\n\n#nope\n";
    let expected: BTreeSet<String> = ["title", "notes", "notes-1"]
        .into_iter()
        .map(String::from)
        .collect();
    assert_eq!(anchors(text), expected);
}

#[test]
fn links_are_found_where_markdown_reads_them() {
    let text = "\
See [a](a.md) and ![b](img/b.png \"title\").\n\
`[not](code.md)` and ``[nor `this`](code.md)``\n\
```text\n\
[not](fenced.md)\n\
```\n\
A [link whose text\n\
wraps](wrapped.md#part) and [![badge](badge.svg)](target.md).\n\
[0, 2 pi) is an interval, not a link.\n\
\n\
<https://example.org/x> and [ref]: not.md\n\
[def]: defined.md \"title\"\n\
Interval [0, 1] (not a link) and [with (parens)](p(1).md).\n";
    let found = links(text);
    let found: Vec<(usize, &str)> = found
        .iter()
        .map(|l| (l.line, l.destination.as_str()))
        .collect();
    assert_eq!(
        found,
        vec![
            (1, "a.md"),
            (1, "img/b.png"),
            (7, "wrapped.md#part"),
            (7, "target.md"),
            (7, "badge.svg"),
            (10, "https://example.org/x"),
            (11, "defined.md"),
            (12, "p(1).md"),
        ]
    );
}

#[test]
fn broken_links_are_reported_with_file_and_line() {
    let dir = tempfile::tempdir().unwrap();
    let root = dir.path();
    fs::create_dir_all(root.join("docs")).unwrap();
    fs::write(root.join("picture.png"), b"").unwrap();
    fs::write(
        root.join("README.md"),
        "# Top\n\
         [fine](docs/page.md#a-section) [fine](#top) [fine](picture.png)\n\
         [missing file](docs/gone.md)\n\
         [missing anchor](docs/page.md#no-such-section)\n\
         [missing here](#nowhere)\n\
         [out](../../etc/passwd) [web](https://example..org) [ok](https://example.org/a?b=1#c)\n\
         [scheme](ftp://example.org/file) [png anchor](picture.png#top)\n",
    )
    .unwrap();
    fs::write(
        root.join("docs/page.md"),
        "# Page\n\n## A section\n\n[back](../README.md#top) [broken back](../README.md#bottom)\n",
    )
    .unwrap();
    let files = documentation(root);
    assert_eq!(
        files,
        vec![
            PathBuf::from("DESIGN.md"),
            PathBuf::from("README.md"),
            PathBuf::from("docs/page.md")
        ]
    );
    // DESIGN.md is always listed; this tree has none, so the check leaves it out.
    let problems = check(root, &files[1..]);
    let located: Vec<&str> = problems
        .iter()
        .map(|p| p.split(": ").next().unwrap())
        .collect();
    assert_eq!(
        located,
        vec![
            "README.md:3",
            "README.md:4",
            "README.md:5",
            "README.md:6",
            "README.md:6",
            "README.md:7",
            "README.md:7",
            "docs/page.md:5",
        ],
        "{problems:#?}"
    );
    assert!(problems[0].contains("docs/gone.md"), "{}", problems[0]);
    assert!(problems[1].contains("#no-such-section"), "{}", problems[1]);
    assert!(problems[4].contains("example..org"), "{}", problems[4]);
    assert!(problems[7].contains("#bottom"), "{}", problems[7]);
}
