//! Fuzzes the Mitsuba XML importer: random edits of the real y-tal scene (byte ranges
//! deleted, duplicated or replaced, random ASCII inserted) must give `Ok` or `Err`, never
//! a panic.

use proptest::prelude::*;
use std::path::{Path, PathBuf};
use umbra::scene::mitsuba_xml;

fn ytal_dir() -> PathBuf {
    PathBuf::from(concat!(env!("CARGO_MANIFEST_DIR"), "/tests/data/ytal"))
}

fn ytal_xml() -> &'static [u8] {
    static TEXT: std::sync::OnceLock<Vec<u8>> = std::sync::OnceLock::new();
    TEXT.get_or_init(|| std::fs::read(ytal_dir().join("nlos_scene.xml")).unwrap())
}

#[derive(Clone, Debug)]
enum Edit {
    Delete { at: usize, len: usize },
    Duplicate { at: usize, len: usize },
    Replace { at: usize, len: usize, with: String },
    Insert { at: usize, text: String },
}

/// Text that tends to hit interesting paths: markup characters, numbers, `$`.
fn snippet() -> impl Strategy<Value = String> {
    prop_oneof![
        "[ -~]{0,12}",
        "[<>/=\"$ 0-9.eE+-]{1,6}",
        Just("nan".to_string()),
        Just("-1".to_string()),
        Just("1e39".to_string()),
        Just("$x".to_string()),
        Just("<default name=\"x\" value=\"2\"/>".to_string()),
        Just("<ref id=\"a\"/>".to_string()),
        Just("<lookat origin=\"0,0,1\" target=\"0,0,0\"/>".to_string()),
        Just("<matrix value=\"1 0 0 0 0 1 0 0 0 0 1 0 0 0 0 1\"/>".to_string()),
    ]
}

fn edit() -> impl Strategy<Value = Edit> {
    let n = ytal_xml().len();
    prop_oneof![
        (0..n, 1..40usize).prop_map(|(at, len)| Edit::Delete { at, len }),
        (0..n, 1..200usize).prop_map(|(at, len)| Edit::Duplicate { at, len }),
        (0..n, 1..8usize, snippet()).prop_map(|(at, len, with)| Edit::Replace { at, len, with }),
        (0..=n, snippet()).prop_map(|(at, text)| Edit::Insert { at, text }),
    ]
}

fn apply(text: &mut Vec<u8>, e: &Edit) {
    let n = text.len();
    let range = |at: usize, len: usize| at.min(n)..(at + len).min(n);
    match e {
        Edit::Delete { at, len } => {
            text.drain(range(*at, *len));
        }
        Edit::Duplicate { at, len } => {
            let r = range(*at, *len);
            let copy = text[r.clone()].to_vec();
            text.splice(r.end..r.end, copy);
        }
        Edit::Replace { at, len, with } => {
            text.splice(range(*at, *len), with.bytes());
        }
        Edit::Insert { at, text: t } => {
            let at = (*at).min(n);
            text.splice(at..at, t.bytes());
        }
    }
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 400, failure_persistence: None, ..ProptestConfig::default() })]

    #[test]
    fn parse_never_panics(edits in prop::collection::vec(edit(), 1..5)) {
        let mut bytes = ytal_xml().to_vec();
        for e in &edits {
            apply(&mut bytes, e);
        }
        let text = String::from_utf8_lossy(&bytes);
        let _ = mitsuba_xml::parse(&text, Path::new("fuzz.xml"), &ytal_dir());
    }
}

/// Byte ranges of the attribute values (inside the quotes) of the y-tal scene.
fn value_spans() -> Vec<(usize, usize)> {
    let t = ytal_xml();
    let quotes: Vec<usize> = (0..t.len()).filter(|&i| t[i] == b'"').collect();
    quotes.chunks_exact(2).map(|q| (q[0] + 1, q[1])).collect()
}

/// Values that reach the scene builder's checks.
fn value() -> impl Strategy<Value = String> {
    prop_oneof![
        "-?[0-9]{1,3}(\\.[0-9]{1,3})?",
        "[0-9., -]{0,12}",
        "[a-z_]{0,10}",
        prop::sample::select(vec![
            "",
            "nan",
            "inf",
            "-1",
            "0",
            "1e30",
            "-1e-30",
            "true",
            "false",
            "box",
            "gaussian",
            "single",
            "confocal",
            "exhaustive",
            "2",
            "3",
            "0, 0, 1",
            "1, 2",
            "$x",
            "a:1",
            "twosided",
            "rectangle",
            "obj",
            "lookat",
            "L.obj",
            "/",
            "4294967296",
        ])
        .prop_map(str::to_string),
    ]
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 400, failure_persistence: None, ..ProptestConfig::default() })]

    /// Well-formed XML with random attribute values: exercises the scene builder.
    #[test]
    fn value_edits_never_panic(edits in prop::collection::vec((any::<prop::sample::Index>(), value()), 1..4)) {
        let spans = value_spans();
        let mut chosen: Vec<(usize, usize, String)> = edits
            .into_iter()
            .map(|(i, v)| { let (a, b) = spans[i.index(spans.len())]; (a, b, v) })
            .collect();
        chosen.sort_by_key(|c| std::cmp::Reverse(c.0));
        chosen.dedup_by_key(|c| c.0);
        let mut bytes = ytal_xml().to_vec();
        for (a, b, v) in chosen {
            bytes.splice(a..b, v.bytes());
        }
        let text = String::from_utf8(bytes).unwrap();
        let _ = mitsuba_xml::parse(&text, Path::new("fuzz.xml"), &ytal_dir());
    }
}

#[test]
fn unmodified_scene_parses() {
    let text = std::str::from_utf8(ytal_xml()).unwrap();
    mitsuba_xml::parse(text, Path::new("nlos_scene.xml"), &ytal_dir()).unwrap();
}
