//! A small XML tree with line numbers, read with quick-xml, and Mitsuba's
//! `<default name=".." value=".."/>` + `$name` substitution.

use crate::error::{Error, Result};
use quick_xml::events::{BytesStart, Event};
use quick_xml::Reader;
use std::collections::{HashMap, HashSet};
use std::path::Path;

/// One attribute, its value already unescaped (and `$name`-substituted after [`parse`]).
pub(crate) struct Attr {
    pub key: String,
    pub value: String,
    pub line: usize,
}

/// One element: its tag, attributes, child elements and the line of its `<`.
pub(crate) struct Node {
    pub tag: String,
    pub attrs: Vec<Attr>,
    pub children: Vec<Node>,
    pub line: usize,
}

impl Node {
    pub fn attr(&self, key: &str) -> Option<&str> {
        self.attrs
            .iter()
            .find(|a| a.key == key)
            .map(|a| a.value.as_str())
    }

    /// Line of attribute `key` (it may sit on a later line than the element's `<`).
    pub fn attr_line(&self, key: &str) -> usize {
        self.attrs
            .iter()
            .find(|a| a.key == key)
            .map_or(self.line, |a| a.line)
    }

    /// `<tag type="..">` (or `<tag name="..">`, or `<tag>`), for messages.
    pub fn label(&self) -> String {
        for key in ["type", "name"] {
            if let Some(v) = self.attr(key) {
                return format!("<{} {key}=\"{v}\">", self.tag);
            }
        }
        format!("<{}>", self.tag)
    }
}

/// Byte offset -> 1-based line number.
struct Lines(Vec<usize>);

impl Lines {
    fn new(text: &str) -> Self {
        let starts = std::iter::once(0)
            .chain(text.match_indices('\n').map(|(i, _)| i + 1))
            .collect();
        Lines(starts)
    }
    fn line(&self, pos: usize) -> usize {
        self.0.partition_point(|&s| s <= pos).max(1)
    }
}

/// Deepest element nesting accepted. Mitsuba scenes nest about 5 deep (scene, shape,
/// bsdf, nested bsdf, value); the bound keeps every recursive pass over the tree (and
/// dropping it) far from the stack's limit, which 40,000 nested elements overflowed.
pub(crate) const MAX_DEPTH: usize = 64;

/// The parsed file: its root element, the `<default>` names it declares (in document
/// order) and the `$name`s it references.
pub(crate) struct Parsed {
    pub root: Node,
    pub declared: Vec<String>,
    pub referenced: HashSet<String>,
}

/// Parses `text` into its root element and applies `$name` substitution from the
/// root's `<default>` children (which stay in the tree: the scene builder skips them).
/// A define the file never references is the caller's to judge ([`unused_defines`]).
pub(crate) fn parse(text: &str, origin: &Path, defines: &[(String, String)]) -> Result<Parsed> {
    let lines = Lines::new(text);
    let err = |pos: usize, msg: String| Error::line(origin, lines.line(pos), msg);
    let mut reader = Reader::from_str(text);
    let mut stack: Vec<Node> = Vec::new();
    let mut root: Option<Node> = None;
    loop {
        let start = reader.buffer_position() as usize;
        let event = reader.read_event().map_err(|e| {
            err(
                reader.error_position() as usize,
                format!("malformed XML: {e}"),
            )
        })?;
        let done = match event {
            Event::Start(e) => {
                if stack.len() >= MAX_DEPTH {
                    return Err(err(
                        start,
                        format!("elements nested more than {MAX_DEPTH} deep (a Mitsuba scene nests about 5)"),
                    ));
                }
                stack.push(node(&e, start, &lines, origin)?);
                None
            }
            Event::Empty(e) => Some(node(&e, start, &lines, origin)?),
            Event::End(_) => match stack.pop() {
                Some(n) => Some(n),
                None => return Err(err(start, "closing tag without an opening tag".into())),
            },
            Event::Text(t) => {
                if !t.iter().all(|b| b.is_ascii_whitespace()) {
                    let where_ = stack.last().map_or("outside the root element".into(), |n| {
                        format!("inside {}", n.label())
                    });
                    return Err(err(start, format!("unexpected text {where_}")));
                }
                None
            }
            Event::CData(_) => return Err(err(start, "unexpected CDATA section".into())),
            Event::Comment(_) | Event::Decl(_) | Event::PI(_) | Event::DocType(_) => None,
            Event::Eof => break,
        };
        if let Some(n) = done {
            match stack.last_mut() {
                Some(parent) => parent.children.push(n),
                None if root.is_none() => root = Some(n),
                None => {
                    return Err(Error::line(
                        origin,
                        n.line,
                        format!("a second root element {}", n.label()),
                    ))
                }
            }
        }
    }
    if let Some(open) = stack.last() {
        return Err(Error::line(
            origin,
            open.line,
            format!("{} is never closed", open.label()),
        ));
    }
    let mut root = root.ok_or_else(|| Error::scene(origin, "no XML element in the file"))?;
    let (declared, referenced) = substitute_defaults(&mut root, origin, defines)?;
    Ok(Parsed {
        root,
        declared,
        referenced,
    })
}

/// Mitsuba refuses a `-D name=value` whose `$name` the file never uses ("Found unused
/// parameters"): the same error here, naming them and the file's own parameters.
pub(crate) fn unused_defines(
    parsed: &Parsed,
    origin: &Path,
    defines: &[(String, String)],
) -> Result<()> {
    let unused: Vec<String> = defines
        .iter()
        .filter(|(n, _)| !parsed.referenced.contains(n))
        .map(|(n, v)| format!("-D {n}={v}"))
        .collect();
    if unused.is_empty() {
        return Ok(());
    }
    let mut used: Vec<&str> = parsed.referenced.iter().map(String::as_str).collect();
    used.sort_unstable();
    let list = |v: &[&str]| {
        if v.is_empty() {
            "none".to_string()
        } else {
            v.iter()
                .map(|n| format!("${n}"))
                .collect::<Vec<_>>()
                .join(", ")
        }
    };
    let declared: Vec<&str> = parsed.declared.iter().map(String::as_str).collect();
    Err(Error::scene(
        origin,
        format!(
            "unused parameter(s) {}: the scene never uses them (Mitsuba refuses them too). It declares <default>s: {}; it uses: {}",
            unused.join(", "),
            list(&declared),
            list(&used)
        ),
    ))
}

fn node(e: &BytesStart, start: usize, lines: &Lines, origin: &Path) -> Result<Node> {
    let line = lines.line(start);
    let tag = String::from_utf8_lossy(e.name().as_ref()).into_owned();
    let raw: &[u8] = e;
    let mut cursor = 0usize;
    let mut attrs = Vec::new();
    for a in e.attributes() {
        let a = a.map_err(|x| Error::line(origin, line, format!("<{tag}>: bad attribute: {x}")))?;
        let key = String::from_utf8_lossy(a.key.as_ref()).into_owned();
        let value = a
            .unescape_value()
            .map_err(|x| Error::line(origin, line, format!("<{tag}>: attribute {key}: {x}")))?
            .into_owned();
        // Find the key in the raw tag (after the previous one) for its line.
        let found = (cursor..raw.len()).find(|&i| {
            let after = &raw[(i + key.len()).min(raw.len())..];
            raw[i..].starts_with(key.as_bytes())
                && i > 0
                && raw[i - 1].is_ascii_whitespace()
                && after.iter().find(|b| !b.is_ascii_whitespace()) == Some(&b'=')
        });
        let attr_line = match found {
            Some(i) => {
                cursor = i + key.len();
                lines.line(start + 1 + i)
            }
            None => line,
        };
        attrs.push(Attr {
            key,
            value,
            line: attr_line,
        });
    }
    Ok(Node {
        tag,
        attrs,
        children: Vec::new(),
        line,
    })
}

/// Mitsuba's `<default name="x" value="v"/>` (top level only) defines `$x` for every
/// attribute value in the file. An undefined `$name` is an error. `defines` (the
/// command line's `-D name=value`, as Mitsuba's) override or add to the defaults.
fn substitute_defaults(
    root: &mut Node,
    origin: &Path,
    defines: &[(String, String)],
) -> Result<(Vec<String>, HashSet<String>)> {
    let mut defs: HashMap<String, String> = HashMap::new();
    let mut declared = Vec::new();
    for d in root.children.iter().filter(|c| c.tag == "default") {
        let (Some(name), Some(value)) = (d.attr("name"), d.attr("value")) else {
            return Err(Error::line(
                origin,
                d.line,
                "<default> needs both name and value attributes",
            ));
        };
        if let Some(a) = d.attrs.iter().find(|a| a.key != "name" && a.key != "value") {
            return Err(Error::line(
                origin,
                a.line,
                format!("<default>: unknown attribute '{}'", a.key),
            ));
        }
        if name.is_empty() || !name.chars().all(is_ident) {
            return Err(Error::line(
                origin,
                d.line,
                format!("<default>: '{name}' is not a valid parameter name"),
            ));
        }
        declared.push(name.to_string());
        if defs.insert(name.to_string(), value.to_string()).is_some() {
            return Err(Error::line(
                origin,
                d.line,
                format!("<default name=\"{name}\"> is defined twice"),
            ));
        }
    }
    for (name, value) in defines {
        defs.insert(name.clone(), value.clone());
    }
    let mut referenced = HashSet::new();
    substitute(root, &defs, &mut referenced, origin, true)?;
    Ok((declared, referenced))
}

fn is_ident(c: char) -> bool {
    c.is_ascii_alphanumeric() || c == '_'
}

fn substitute(
    n: &mut Node,
    defs: &HashMap<String, String>,
    referenced: &mut HashSet<String>,
    origin: &Path,
    is_root: bool,
) -> Result<()> {
    for a in &mut n.attrs {
        if a.value.contains('$') {
            a.value = expand(&a.value, defs, referenced).map_err(|name| {
                Error::line(
                    origin,
                    a.line,
                    format!(
                        "<{}>: attribute {}: '${name}' is not defined by a <default name=\"{name}\" value=\"..\"/>",
                        n.tag, a.key
                    ),
                )
            })?;
        }
    }
    for c in &mut n.children {
        // The defaults' own values are taken literally.
        if !(is_root && c.tag == "default") {
            substitute(c, defs, referenced, origin, false)?;
        }
    }
    Ok(())
}

/// Replaces each `$name` in `s`; `Err(name)` for an undefined one. A `$` not followed by
/// a name is kept.
fn expand(
    s: &str,
    defs: &HashMap<String, String>,
    referenced: &mut HashSet<String>,
) -> std::result::Result<String, String> {
    let mut out = String::with_capacity(s.len());
    let mut rest = s;
    while let Some(i) = rest.find('$') {
        out.push_str(&rest[..i]);
        let after = &rest[i + 1..];
        let len = after.find(|c: char| !is_ident(c)).unwrap_or(after.len());
        if len == 0 {
            out.push('$');
        } else {
            let name = &after[..len];
            referenced.insert(name.to_string());
            out.push_str(defs.get(name).ok_or_else(|| name.to_string())?);
        }
        rest = &after[len..];
    }
    out.push_str(rest);
    Ok(out)
}
