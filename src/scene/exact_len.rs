//! Fixed-length TOML arrays read strictly: serde's `[T; N]` takes the first `N` values of
//! a longer array and drops the rest without a word (`resolution = [8, 8, 8]`, a
//! five-value `origin`), so the scene readers deserialize such fields through these,
//! which refuse any other length, saying how many values were given.

use serde::de::{DeserializeOwned, Deserializer, Error};
use serde::Deserialize;

/// An array of exactly `N` values.
pub fn exact<'de, D, T, const N: usize>(d: D) -> Result<[T; N], D::Error>
where
    D: Deserializer<'de>,
    T: DeserializeOwned,
{
    let v: Vec<T> = Vec::deserialize(d)?;
    let n = v.len();
    v.try_into()
        .map_err(|_| D::Error::custom(format!("expected an array of {N} values, got {n}")))
}

/// An optional array of exactly `N` values.
pub fn exact_opt<'de, D, T, const N: usize>(d: D) -> Result<Option<[T; N]>, D::Error>
where
    D: Deserializer<'de>,
    T: DeserializeOwned,
{
    exact(d).map(Some)
}

/// An optional `R x C` matrix (an array of `R` arrays of `C` values).
pub fn exact_matrix_opt<'de, D, const R: usize, const C: usize>(
    d: D,
) -> Result<Option<[[f32; C]; R]>, D::Error>
where
    D: Deserializer<'de>,
{
    let rows: Vec<Vec<f32>> = Vec::deserialize(d)?;
    if rows.len() != R || rows.iter().any(|r| r.len() != C) {
        let lens: Vec<usize> = rows.iter().map(Vec::len).collect();
        return Err(D::Error::custom(format!(
            "expected {R} rows of {C} values, got {} rows of {lens:?} values",
            rows.len()
        )));
    }
    let mut m = [[0.0; C]; R];
    for (row, r) in m.iter_mut().zip(rows) {
        row.copy_from_slice(&r);
    }
    Ok(Some(m))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[derive(Deserialize, Debug)]
    struct T {
        #[serde(deserialize_with = "exact")]
        a: [u32; 2],
        #[serde(default, deserialize_with = "exact_opt")]
        b: Option<[f32; 3]>,
        #[serde(default, deserialize_with = "exact_matrix_opt")]
        m: Option<[[f32; 2]; 2]>,
    }

    #[test]
    fn lengths_other_than_n_are_refused() {
        let ok: T = toml::from_str("a = [1, 2]\nb = [1, 2, 3]\nm = [[1, 0], [0, 1]]").unwrap();
        assert_eq!(
            (ok.a, ok.b, ok.m),
            (
                [1, 2],
                Some([1.0, 2.0, 3.0]),
                Some([[1.0, 0.0], [0.0, 1.0]])
            )
        );
        let none: T = toml::from_str("a = [1, 2]").unwrap();
        assert_eq!((none.b, none.m), (None, None));
        for (text, says) in [
            ("a = [8, 8, 8]", "expected an array of 2 values, got 3"),
            ("a = [8]", "expected an array of 2 values, got 1"),
            (
                "a = [1, 2]\nb = [1, 2, 3, 4, 5]",
                "expected an array of 3 values, got 5",
            ),
            (
                "a = [1, 2]\nm = [[1, 0, 0], [0, 1]]",
                "expected 2 rows of 2 values, got 2 rows of [3, 2] values",
            ),
        ] {
            let e = toml::from_str::<T>(text).unwrap_err().to_string();
            assert!(e.contains(says), "{text}: {e}");
        }
    }
}
