//! Reading a launch file: TOML syntax, the typed sections (unknown keys and wrong types are
//! errors), relative paths resolved against the file's folder, then the semantic checks of
//! [`crate::validate`]. Every problem is reported as an [`Issue`] with the file, line, column
//! and dotted key, using the spans of toml's `DeTable` document.

use crate::LaunchFile;
use std::fmt;
use std::ops::Range;
use std::path::{Path, PathBuf};
use toml::de::{DeTable, DeValue};
use toml::Spanned;

/// One problem in a launch file.
#[derive(Debug, Clone, PartialEq)]
pub struct Issue {
    /// Dotted key, e.g. `scene.meniscus.mesh` or `scene.gravity[2]`; `<document>` when the
    /// problem is not tied to one key.
    pub key: String,
    /// 1-based line and column of the key in the file, when the key is written in it.
    pub line: Option<usize>,
    pub column: Option<usize>,
    /// What is wrong and what is allowed.
    pub message: String,
}

impl Issue {
    /// An issue about `key`, located later by [`SpanIndex::locate_key`].
    pub fn at_key(key: impl Into<String>, message: impl Into<String>) -> Issue {
        Issue {
            key: key.into(),
            line: None,
            column: None,
            message: message.into(),
        }
    }
}

impl fmt::Display for Issue {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match (self.line, self.column) {
            (Some(l), Some(c)) => write!(f, "line {l}, column {c}: ")?,
            (Some(l), None) => write!(f, "line {l}: ")?,
            _ => write!(f, "(default value): ")?,
        }
        write!(f, "key `{}`: {}", self.key, self.message)
    }
}

/// Failure to load a launch file.
#[derive(Debug, thiserror::Error)]
pub enum LaunchError {
    #[error("{}: cannot read launch file: {source}", path.display())]
    Read {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("{}", render_issues(origin, issues))]
    Invalid { origin: String, issues: Vec<Issue> },
}

impl LaunchError {
    /// The issues of an invalid file (empty for a read error).
    pub fn issues(&self) -> &[Issue] {
        match self {
            LaunchError::Invalid { issues, .. } => issues,
            LaunchError::Read { .. } => &[],
        }
    }
}

fn render_issues(origin: &str, issues: &[Issue]) -> String {
    let mut text = String::new();
    for (i, issue) in issues.iter().enumerate() {
        if i > 0 {
            text.push('\n');
        }
        match (issue.line, issue.column) {
            (Some(l), Some(c)) => text.push_str(&format!("{origin}:{l}:{c}: ")),
            (Some(l), None) => text.push_str(&format!("{origin}:{l}: ")),
            _ => text.push_str(&format!("{origin}: ")),
        }
        text.push_str(&format!("key `{}`: {}", issue.key, issue.message));
    }
    text
}

/// Loads, resolves and validates the launch file at `path`.
pub fn load(path: impl AsRef<Path>) -> Result<LaunchFile, LaunchError> {
    let path = path.as_ref();
    let text = std::fs::read_to_string(path).map_err(|source| LaunchError::Read {
        path: path.to_path_buf(),
        source,
    })?;
    load_str(&text, path)
}

/// Loads launch-file text that came from `origin` (its folder resolves relative paths; an
/// origin without a folder, such as the embedded default, resolves against the working
/// directory), then validates it.
pub fn load_str(text: &str, origin: impl AsRef<Path>) -> Result<LaunchFile, LaunchError> {
    let origin = origin.as_ref();
    let origin_name = origin.display().to_string();
    let (mut file, choice_issues) = parse_collecting(text, &origin_name)?;
    let base = origin
        .parent()
        .filter(|p| !p.as_os_str().is_empty())
        .map(Path::to_path_buf)
        .unwrap_or_else(|| PathBuf::from("."));
    resolve_paths(&mut file, &base);
    let mut issues = crate::validate(&file);
    if issues.is_empty() && choice_issues.is_empty() {
        return Ok(file);
    }
    // The text parsed above, so the spanned document parses too.
    if let Ok(doc) = DeTable::parse(text) {
        let index = SpanIndex::new(doc.get_ref());
        for issue in &mut issues {
            if let Some(span) = index.locate_key(&issue.key) {
                let (l, c) = line_column(text, span.start);
                issue.line = Some(l);
                issue.column = Some(c);
            }
        }
    }
    // Choice issues come first, in file order.
    let mut all = choice_issues;
    all.append(&mut issues);
    Err(LaunchError::Invalid {
        origin: origin_name,
        issues: all,
    })
}

/// Parses and type-checks launch-file text without resolving paths or checking values.
pub fn parse_str(text: &str, origin: &str) -> Result<LaunchFile, LaunchError> {
    match parse_collecting(text, origin)? {
        (file, issues) if issues.is_empty() => Ok(file),
        (_, issues) => Err(LaunchError::Invalid {
            origin: origin.to_string(),
            issues,
        }),
    }
}

/// Most unknown choices one parse collects before it gives up.
const MAX_CHOICE_ISSUES: usize = 64;

/// Parses and type-checks the text. A choice (an enum such as `[device] backend`) with an
/// unknown value becomes an issue and is read as its default, so parsing goes on and every
/// bad choice, and every other problem, is reported at once; any other type error ends the
/// parse with that one issue.
fn parse_collecting(text: &str, origin: &str) -> Result<(LaunchFile, Vec<Issue>), LaunchError> {
    let invalid = |issues: Vec<Issue>| LaunchError::Invalid {
        origin: origin.to_string(),
        issues,
    };
    if let Err(e) = DeTable::parse(text) {
        return Err(invalid(vec![syntax_issue(text, &e)]));
    }
    let defaults = toml::Value::try_from(LaunchFile::default()).ok();
    let mut patched = text.to_string();
    let mut issues = Vec::new();
    loop {
        let e = match toml::from_str::<LaunchFile>(&patched) {
            Ok(file) => {
                // serde meets the keys in struct order: report them in file order.
                issues.sort_by_key(|i: &Issue| (i.line, i.column));
                return Ok((file, issues));
            }
            Err(e) => e,
        };
        // The patched text still parses: only quoted values were replaced by quoted values.
        let doc = DeTable::parse(&patched).map_err(|e| invalid(vec![syntax_issue(text, &e)]))?;
        let index = SpanIndex::new(doc.get_ref());
        let key = match e.span() {
            Some(span) => index.key_at(span.start),
            None => "<document>".to_string(),
        };
        let message = e.message().trim_end();
        let unknown_choice = unknown_variant(message);
        // A bad choice is located at its key, like the value checks of `crate::validate`;
        // other errors where toml found them.
        let at = match unknown_choice {
            Some(_) => index.locate_key(&key).or(e.span()),
            None => e.span(),
        };
        let (line, column) = match at {
            Some(span) => {
                let (l, c) = line_column(&patched, span.start);
                (Some(l), Some(c))
            }
            None => (None, None),
        };
        issues.push(Issue {
            key: key.clone(),
            line,
            column,
            message: match &unknown_choice {
                Some((value, allowed)) => {
                    crate::choices::not_allowed(value, allowed.iter().map(String::as_str))
                }
                None => explain(message),
            },
        });
        // Read an unknown choice as its default (else its first allowed value) and go on.
        let replacement = match (unknown_choice, e.span()) {
            (Some((_, allowed)), Some(span))
                if issues.len() < MAX_CHOICE_ISSUES
                    && patched
                        .get(span.clone())
                        .is_some_and(|v| v.starts_with(['"', '\'']) && !v.contains('\n')) =>
            {
                let default = defaults
                    .as_ref()
                    .and_then(|d| default_string(d, &key))
                    .or(allowed.into_iter().next());
                default.map(|d| (span, d))
            }
            _ => None,
        };
        match replacement {
            Some((span, value)) => patched.replace_range(span, &format!("{value:?}")),
            None => return Err(invalid(issues)),
        }
    }
}

/// serde's "unknown variant `x`, expected one of `a`, `b`" (or "expected `a` or `b`"):
/// the value and the allowed values.
fn unknown_variant(message: &str) -> Option<(String, Vec<String>)> {
    if !message.starts_with("unknown variant") {
        return None;
    }
    let mut quoted = message.split('`').skip(1).step_by(2).map(str::to_string);
    let value = quoted.next()?;
    let allowed: Vec<String> = quoted.collect();
    (!allowed.is_empty()).then_some((value, allowed))
}

/// The string at a dotted key of the defaults document.
fn default_string(defaults: &toml::Value, key: &str) -> Option<String> {
    key.split('.')
        .try_fold(defaults, |v, k| v.get(k))?
        .as_str()
        .map(str::to_string)
}

/// toml/serde messages, with the allowed alternatives spelled out where serde does not.
fn explain(message: &str) -> String {
    if message.starts_with("unknown field") {
        // serde already says "expected one of `a`, `b`": the allowed keys.
        format!("{message} (unknown keys are errors)")
    } else {
        message.to_string()
    }
}

fn syntax_issue(text: &str, e: &toml::de::Error) -> Issue {
    let (line, column) = match e.span() {
        Some(s) => {
            let (l, c) = line_column(text, s.start);
            (Some(l), Some(c))
        }
        None => (None, None),
    };
    // Name the key on the offending line when the rest of the document can be recovered.
    let key = match (e.span(), DeTable::parse_recoverable(text)) {
        (Some(span), (doc, _)) => {
            let index = SpanIndex::new(doc.get_ref());
            index
                .key_on_line(text, span.start)
                .unwrap_or_else(|| "<document>".into())
        }
        _ => "<document>".into(),
    };
    Issue {
        key,
        line,
        column,
        message: format!("TOML syntax error: {}", e.message().trim_end()),
    }
}

/// 1-based (line, column) of a byte offset; the column counts characters.
pub fn line_column(text: &str, offset: usize) -> (usize, usize) {
    let offset = offset.min(text.len());
    let before = &text[..floor_char_boundary(text, offset)];
    let line = before.matches('\n').count() + 1;
    let line_start = before.rfind('\n').map(|i| i + 1).unwrap_or(0);
    let column = before[line_start..].chars().count() + 1;
    (line, column)
}

fn floor_char_boundary(text: &str, mut i: usize) -> usize {
    while i > 0 && !text.is_char_boundary(i) {
        i -= 1;
    }
    i
}

/// Every key of a parsed document with the spans of its key and value.
pub struct SpanIndex {
    entries: Vec<SpanEntry>,
}

struct SpanEntry {
    path: String,
    key: Range<usize>,
    value: Range<usize>,
}

impl SpanIndex {
    pub fn new(doc: &DeTable<'_>) -> SpanIndex {
        let mut entries = Vec::new();
        collect_table(doc, "", &mut entries);
        SpanIndex { entries }
    }

    /// Span of the key `path` (dotted, `[i]` for array elements), if written in the file.
    pub fn locate_key(&self, path: &str) -> Option<Range<usize>> {
        if let Some(e) = self.entries.iter().find(|e| e.path == path) {
            return Some(e.key.clone());
        }
        // A key that is not written (a default) but whose table is: point at the table.
        let mut parent = path;
        while let Some(i) = parent.rfind(['.', '[']) {
            parent = &parent[..i];
            if let Some(e) = self.entries.iter().find(|e| e.path == parent) {
                return Some(e.key.clone());
            }
        }
        None
    }

    /// The innermost key whose key or value span contains `offset`.
    pub fn key_at(&self, offset: usize) -> String {
        self.entries
            .iter()
            .filter(|e| e.key.contains(&offset) || e.value.contains(&offset))
            // Innermost = longest path among the matches (children are listed after parents).
            .max_by_key(|e| e.path.len())
            .map(|e| e.path.clone())
            .unwrap_or_else(|| "<document>".into())
    }

    /// The last key written on the line of `offset`, or the table it belongs to.
    fn key_on_line(&self, text: &str, offset: usize) -> Option<String> {
        let (line, _) = line_column(text, offset);
        self.entries
            .iter()
            .filter(|e| line_column(text, e.key.start).0 <= line)
            .max_by_key(|e| e.key.start)
            .map(|e| e.path.clone())
    }
}

fn collect_table(table: &DeTable<'_>, prefix: &str, out: &mut Vec<SpanEntry>) {
    for (key, value) in table.iter() {
        let path = if prefix.is_empty() {
            key.get_ref().to_string()
        } else {
            format!("{prefix}.{}", key.get_ref())
        };
        out.push(SpanEntry {
            path: path.clone(),
            key: key.span(),
            value: value.span(),
        });
        collect_value(value, &path, out);
    }
}

fn collect_value(value: &Spanned<DeValue<'_>>, path: &str, out: &mut Vec<SpanEntry>) {
    match value.get_ref() {
        DeValue::Table(t) => collect_table(t, path, out),
        DeValue::Array(items) => {
            for (i, item) in items.iter().enumerate() {
                let item_path = format!("{path}[{i}]");
                out.push(SpanEntry {
                    path: item_path.clone(),
                    key: item.span(),
                    value: item.span(),
                });
                collect_value(item, &item_path, out);
            }
        }
        _ => {}
    }
}

/// True for a mesh or file spec naming a built-in model rather than a file.
pub fn is_builtin_spec(spec: &str) -> bool {
    spec.starts_with("default:") || spec.starts_with("study:")
}

/// Makes the file paths of a launch file absolute, relative ones against `base` (the launch
/// file's folder), so nodes started from any working directory find the same files.
pub fn resolve_paths(file: &mut LaunchFile, base: &Path) {
    let base = std::path::absolute(base).unwrap_or_else(|_| base.to_path_buf());
    let resolve = |spec: &mut String| {
        if spec.is_empty() || is_builtin_spec(spec) {
            return;
        }
        let p = Path::new(spec.as_str());
        if p.is_relative() {
            *spec = base.join(p).to_string_lossy().into_owned();
        }
    };
    let meniscus = &mut file.scene.meniscus;
    resolve(&mut meniscus.mesh);
    if let Some(visual) = meniscus.visual.as_mut() {
        resolve(visual);
    }
    if !matches!(meniscus.fixed.as_str(), "inferior" | "none") {
        resolve(&mut meniscus.fixed);
    }
    if !crate::scene::BUILTIN_PROBE_MODELS.contains(&file.scene.probe.model.as_str()) {
        resolve(&mut file.scene.probe.model);
    }
    resolve(&mut file.device.replay.path);
}
