//! A hidden object's index as Python writes one: negative counts from the end
//! (`scene.vertices(-1)` is the last object's), and any int is taken, so an index out of
//! range is refused naming it and the valid range (a bare `OverflowError` before).

use crate::UmbraError;
use pyo3::prelude::*;

/// An index as given: its value when it fits an `i64`, and its text for messages.
pub struct ObjectIndex {
    value: Option<i64>,
    text: String,
}

impl ObjectIndex {
    /// The first object (the methods' default).
    pub const FIRST: ObjectIndex = ObjectIndex {
        value: Some(0),
        text: String::new(),
    };

    /// The object `0..n` this index names, or an `UmbraError` naming it and the range.
    pub fn resolve(&self, n: usize) -> PyResult<usize> {
        let n64 = i64::try_from(n).unwrap_or(i64::MAX);
        match self.value {
            Some(i) if (0..n64).contains(&i) => return Ok(i as usize),
            Some(i) if (-n64..0).contains(&i) => return Ok((n64 + i) as usize),
            _ => {}
        }
        let text = match (self.value, self.text.is_empty()) {
            (Some(i), true) => i.to_string(),
            _ => self.text.clone(),
        };
        let range = match n {
            0 => "none".to_string(),
            _ => format!("0 to {}, or -{n} to -1", n - 1),
        };
        Err(UmbraError::new_err(format!(
            "object {text} does not exist: the scene has {n} hidden object{} ({range})",
            if n == 1 { "" } else { "s" }
        )))
    }
}

impl<'a, 'py> FromPyObject<'a, 'py> for ObjectIndex {
    type Error = PyErr;

    fn extract(obj: pyo3::Borrowed<'a, 'py, PyAny>) -> PyResult<Self> {
        // operator.index: an int or an int-like (numpy integers); a TypeError otherwise,
        // as Python's own indexing.
        let i = obj.py().import("operator")?.call_method1("index", (obj,))?;
        let mut text = i.str()?.to_string();
        if text.len() > 40 {
            text = format!("{}...{}", &text[..16], &text[text.len() - 16..]);
        }
        Ok(ObjectIndex {
            value: i.extract::<i64>().ok(),
            text,
        })
    }
}
