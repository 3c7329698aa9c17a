//! Mitsuba plugin parameters (`<float name=.. value=..>` and friends), read strictly:
//! a parameter nobody asked for is an error, as is a value of the wrong type, a bad
//! number or a non-finite one. Also `<transform name="to_world">`.

use super::tree::Node;
use crate::error::{Error, Result};
use glam::{Mat4, Vec3, Vec4};
use std::path::Path;

/// Where errors and warnings go.
pub(crate) struct Cx<'p> {
    pub origin: &'p Path,
    pub warnings: Vec<String>,
}

impl Cx<'_> {
    pub fn err(&self, line: usize, msg: impl Into<String>) -> Error {
        Error::line(self.origin, line, msg)
    }
    pub fn warn(&mut self, line: usize, msg: impl AsRef<str>) {
        let w = format!("{}:{line}: {}", self.origin.display(), msg.as_ref());
        self.warnings.push(w);
    }
}

const PARAM_TAGS: [&str; 9] = [
    "float",
    "integer",
    "boolean",
    "string",
    "point",
    "vector",
    "rgb",
    "spectrum",
    "transform",
];

/// A plugin element (`<shape>`, `<bsdf>`, `<film>`, ...): its named parameters and its
/// nested objects, each marked when read so that [`Plugin::finish`] can reject the rest.
pub(crate) struct Plugin<'n> {
    pub node: &'n Node,
    pub label: String,
    params: Vec<(&'n str, &'n Node, bool)>,
    objects: Vec<(&'n Node, bool)>,
}

impl<'n> Plugin<'n> {
    /// Checks the element's own attributes (`type`, `id`, `name`) and sorts its children.
    pub fn new(node: &'n Node, cx: &Cx) -> Result<Self> {
        let label = node.label();
        if let Some(a) = node
            .attrs
            .iter()
            .find(|a| !matches!(a.key.as_str(), "type" | "id" | "name"))
        {
            return Err(cx.err(a.line, format!("{label}: unknown attribute '{}'", a.key)));
        }
        if node.attr("type").is_none() {
            return Err(cx.err(node.line, format!("<{}> needs a type attribute", node.tag)));
        }
        let mut params: Vec<(&str, &Node, bool)> = Vec::new();
        let mut objects = Vec::new();
        for c in &node.children {
            if PARAM_TAGS.contains(&c.tag.as_str()) {
                let name = c.attr("name").ok_or_else(|| {
                    cx.err(
                        c.line,
                        format!("{label}: <{}> needs a name attribute", c.tag),
                    )
                })?;
                if params.iter().any(|p| p.0 == name) {
                    return Err(cx.err(
                        c.line,
                        format!("{label}: parameter '{name}' is given twice"),
                    ));
                }
                params.push((name, c, false));
            } else {
                objects.push((c, false));
            }
        }
        Ok(Plugin {
            node,
            label,
            params,
            objects,
        })
    }

    /// Line of parameter `name` (the element's line if absent).
    pub fn line_of(&self, name: &str) -> usize {
        self.params
            .iter()
            .find(|p| p.0 == name)
            .map_or(self.node.line, |p| p.1.line)
    }

    pub fn kind(&self) -> &'n str {
        self.node.attr("type").unwrap_or("")
    }

    /// The parameter `name`, if present, checked to be one of `tags`.
    pub fn take(&mut self, cx: &Cx, name: &str, tags: &[&str]) -> Result<Option<&'n Node>> {
        let Some(p) = self.params.iter_mut().find(|p| p.0 == name) else {
            return Ok(None);
        };
        p.2 = true;
        let n = p.1;
        if !tags.contains(&n.tag.as_str()) {
            let want = tags.iter().map(|t| format!("<{t}>")).collect::<Vec<_>>();
            return Err(cx.err(
                n.line,
                format!(
                    "{}: parameter '{name}' must be {}, not <{}>",
                    self.label,
                    want.join(" or "),
                    n.tag
                ),
            ));
        }
        let allowed: &[&str] = match n.tag.as_str() {
            "point" | "vector" => &["name", "value", "x", "y", "z"],
            "transform" => &["name"],
            _ => &["name", "value"],
        };
        if let Some(a) = n.attrs.iter().find(|a| !allowed.contains(&a.key.as_str())) {
            return Err(cx.err(
                a.line,
                format!("<{} name=\"{name}\">: unknown attribute '{}'", n.tag, a.key),
            ));
        }
        if n.tag != "transform" {
            if let Some(c) = n.children.first() {
                return Err(cx.err(
                    c.line,
                    format!("<{} name=\"{name}\"> has a child element", n.tag),
                ));
            }
        }
        Ok(Some(n))
    }

    fn value<'a>(&self, cx: &Cx, n: &'a Node, name: &str) -> Result<&'a str> {
        n.attr("value").ok_or_else(|| {
            cx.err(
                n.line,
                format!("<{} name=\"{name}\"> needs a value attribute", n.tag),
            )
        })
    }

    pub fn float(&mut self, cx: &Cx, name: &str) -> Result<Option<f32>> {
        let Some(n) = self.take(cx, name, &["float"])? else {
            return Ok(None);
        };
        let v = self.value(cx, n, name)?;
        number(v)
            .map(Some)
            .ok_or_else(|| bad_number(cx, n, name, v))
    }

    pub fn int(&mut self, cx: &Cx, name: &str) -> Result<Option<(i64, usize)>> {
        let Some(n) = self.take(cx, name, &["integer"])? else {
            return Ok(None);
        };
        let v = self.value(cx, n, name)?;
        match v.trim().parse::<i64>() {
            Ok(i) => Ok(Some((i, n.attr_line("value")))),
            Err(_) => Err(cx.err(
                n.attr_line("value"),
                format!("<integer name=\"{name}\">: '{v}' is not an integer"),
            )),
        }
    }

    pub fn bool(&mut self, cx: &Cx, name: &str) -> Result<Option<bool>> {
        let Some(n) = self.take(cx, name, &["boolean"])? else {
            return Ok(None);
        };
        let v = self.value(cx, n, name)?;
        match v.trim().to_ascii_lowercase().as_str() {
            "true" => Ok(Some(true)),
            "false" => Ok(Some(false)),
            _ => Err(cx.err(
                n.attr_line("value"),
                format!("<boolean name=\"{name}\">: '{v}' is neither true nor false"),
            )),
        }
    }

    pub fn string(&mut self, cx: &Cx, name: &str) -> Result<Option<(&'n str, usize)>> {
        let Some(n) = self.take(cx, name, &["string"])? else {
            return Ok(None);
        };
        Ok(Some((self.value(cx, n, name)?, n.line)))
    }

    /// `<point>` or `<vector>`: `x`, `y`, `z` attributes or `value="x, y, z"`.
    pub fn point(&mut self, cx: &Cx, name: &str) -> Result<Option<Vec3>> {
        let Some(n) = self.take(cx, name, &["point", "vector"])? else {
            return Ok(None);
        };
        xyz(cx, n, &format!("<{} name=\"{name}\">", n.tag), None).map(Some)
    }

    /// A monochrome quantity given as `<float>`, `<spectrum>` (one value) or `<rgb>`
    /// (the mean of r, g, b, with a warning when they differ).
    pub fn mono(&mut self, cx: &mut Cx, name: &str) -> Result<Option<f32>> {
        let Some(n) = self.take(cx, name, &["float", "spectrum", "rgb"])? else {
            return Ok(None);
        };
        let v = self.value(cx, n, name)?;
        let what = format!("<{} name=\"{name}\">", n.tag);
        let line = n.attr_line("value");
        let vals = match n.tag.as_str() {
            "float" => vec![number(v).ok_or_else(|| bad_number(cx, n, name, v))?],
            "spectrum" => {
                if v.contains(':') {
                    return Err(cx.err(line, format!("{what}: wavelength:value spectra are not supported (Umbra is monochrome): give one value")));
                }
                vec![number(v).ok_or_else(|| bad_number(cx, n, name, v))?]
            }
            _ => match numbers(v) {
                Some(l) if l.len() == 3 || l.len() == 1 => l,
                _ => {
                    return Err(cx.err(line, format!("{what}: '{v}' is not 1 or 3 finite numbers")))
                }
            },
        };
        // A grey triple is its value exactly (a mean of three f32s may not be).
        let grey = vals.iter().all(|&x| x == vals[0]);
        let mean = if grey {
            vals[0]
        } else {
            vals.iter().sum::<f32>() / vals.len() as f32
        };
        if !grey {
            let lum = 0.2126 * vals[0] + 0.7152 * vals[1] + 0.0722 * vals[2];
            cx.warn(line, format!("{what}: Umbra is monochrome and uses the mean {mean} of '{v}' (Mitsuba's mono variants would use the luminance {lum})"));
        }
        Ok(Some(mean))
    }

    /// `<transform name="..">` as a matrix.
    pub fn transform(&mut self, cx: &Cx, name: &str) -> Result<Option<Mat4>> {
        match self.take(cx, name, &["transform"])? {
            Some(n) => transform(cx, n).map(Some),
            None => Ok(None),
        }
    }

    /// All nested objects with tag `tag` (marked as read).
    pub fn objects(&mut self, tag: &str) -> Vec<&'n Node> {
        let mut out = Vec::new();
        for o in self.objects.iter_mut().filter(|o| o.0.tag == tag) {
            o.1 = true;
            out.push(o.0);
        }
        out
    }

    /// At most one nested object among `tags`.
    pub fn object(&mut self, cx: &Cx, tags: &[&str]) -> Result<Option<&'n Node>> {
        let mut found: Vec<&Node> = Vec::new();
        for t in tags {
            found.extend(self.objects(t));
        }
        found.sort_by_key(|n| n.line);
        if let Some(second) = found.get(1) {
            return Err(cx.err(
                second.line,
                format!(
                    "{}: a second {} (only one is allowed)",
                    self.label,
                    second.label()
                ),
            ));
        }
        Ok(found.first().copied())
    }

    /// Errors on the first parameter or nested object that nobody read.
    pub fn finish(self, cx: &Cx) -> Result<()> {
        if let Some(p) = self.params.iter().find(|p| !p.2) {
            return Err(cx.err(
                p.1.line,
                format!(
                    "{}: unknown parameter '{}' (not in the subset of Mitsuba/mitransient that Umbra reads)",
                    self.label, p.0
                ),
            ));
        }
        if let Some(o) = self.objects.iter().find(|o| !o.1) {
            return Err(cx.err(
                o.0.line,
                format!("{}: unexpected {} inside it", self.label, o.0.label()),
            ));
        }
        Ok(())
    }
}

fn bad_number(cx: &Cx, n: &Node, name: &str, v: &str) -> Error {
    cx.err(
        n.attr_line("value"),
        format!("<{} name=\"{name}\">: '{v}' is not a finite number", n.tag),
    )
}

/// A finite number.
pub(crate) fn number(s: &str) -> Option<f32> {
    s.trim().parse::<f32>().ok().filter(|v| v.is_finite())
}

/// Finite numbers separated by commas and/or whitespace.
pub(crate) fn numbers(s: &str) -> Option<Vec<f32>> {
    s.split(|c: char| c == ',' || c.is_whitespace())
        .filter(|t| !t.is_empty())
        .map(number)
        .collect()
}

/// `x`, `y`, `z` attributes (each defaulting to `default`, or required when `None`), or
/// `value` with one number (all three) or three.
fn xyz(cx: &Cx, n: &Node, what: &str, default: Option<f32>) -> Result<Vec3> {
    if let Some(v) = n.attr("value") {
        if let Some(a) = ["x", "y", "z"].iter().find(|a| n.attr(a).is_some()) {
            return Err(cx.err(
                n.line,
                format!("{what}: give either value or {a}, not both"),
            ));
        }
        return match numbers(v).as_deref() {
            Some(&[a]) => Ok(Vec3::splat(a)),
            Some(&[a, b, c]) => Ok(Vec3::new(a, b, c)),
            _ => Err(cx.err(
                n.attr_line("value"),
                format!("{what}: value '{v}' is not 1 or 3 finite numbers"),
            )),
        };
    }
    let mut out = [0.0f32; 3];
    for (o, k) in out.iter_mut().zip(["x", "y", "z"]) {
        *o = match (n.attr(k), default) {
            (Some(v), _) => number(v).ok_or_else(|| {
                cx.err(
                    n.attr_line(k),
                    format!("{what}: {k} = '{v}' is not a finite number"),
                )
            })?,
            (None, Some(d)) => d,
            (None, None) => return Err(cx.err(n.line, format!("{what}: missing {k}"))),
        };
    }
    Ok(Vec3::from_array(out))
}

/// `<transform>`: its operations composed in document order, each new one applied after
/// the previous ones (`M = op * M`), as Mitsuba does.
pub(crate) fn transform(cx: &Cx, t: &Node) -> Result<Mat4> {
    let mut m = Mat4::IDENTITY;
    for op in &t.children {
        let what = format!("<{}>", op.tag);
        let allowed: &[&str] = match op.tag.as_str() {
            "translate" | "scale" => &["x", "y", "z", "value"],
            "rotate" => &["x", "y", "z", "value", "angle"],
            "matrix" => &["value"],
            "lookat" => &["origin", "target", "up"],
            _ => {
                return Err(cx.err(
                    op.line,
                    format!(
                        "{}: unknown operation <{}> (translate, scale, rotate, matrix, lookat)",
                        t.label(),
                        op.tag
                    ),
                ))
            }
        };
        if let Some(a) = op.attrs.iter().find(|a| !allowed.contains(&a.key.as_str())) {
            return Err(cx.err(a.line, format!("{what}: unknown attribute '{}'", a.key)));
        }
        if let Some(c) = op.children.first() {
            return Err(cx.err(c.line, format!("{what} has a child element")));
        }
        let step = match op.tag.as_str() {
            "translate" => Mat4::from_translation(xyz(cx, op, &what, Some(0.0))?),
            "scale" => Mat4::from_scale(xyz(cx, op, &what, Some(1.0))?),
            "rotate" => {
                let angle = match op.attr("angle").map(|a| (a, number(a))) {
                    Some((_, Some(a))) => a,
                    Some((a, None)) => {
                        return Err(cx.err(
                            op.attr_line("angle"),
                            format!("{what}: angle '{a}' is not a finite number"),
                        ))
                    }
                    None => return Err(cx.err(op.line, format!("{what}: missing angle (degrees)"))),
                };
                let axis = xyz(cx, op, &what, Some(0.0))?;
                if axis.length_squared() < 1e-12 {
                    return Err(cx.err(op.line, format!("{what}: the rotation axis is zero")));
                }
                Mat4::from_axis_angle(axis.normalize(), angle.to_radians())
            }
            "matrix" => matrix(cx, op)?,
            _ => lookat(cx, op)?,
        };
        m = step * m;
    }
    if !m.is_finite() {
        return Err(cx.err(
            t.line,
            format!("{}: the composed matrix is not finite", t.label()),
        ));
    }
    Ok(m)
}

fn matrix(cx: &Cx, op: &Node) -> Result<Mat4> {
    let v = op.attr("value").unwrap_or("");
    let line = op.attr_line("value");
    let m = match numbers(v) {
        // Row-major in the file.
        Some(a) if a.len() == 16 => Mat4::from_cols_slice(&a).transpose(),
        Some(a) if a.len() == 9 => Mat4::from_mat3(glam::Mat3::from_cols_slice(&a).transpose()),
        _ => {
            return Err(cx.err(
                line,
                format!("<matrix>: value must hold 16 (or 9) finite numbers, got '{v}'"),
            ))
        }
    };
    if m.row(3) != Vec4::new(0.0, 0.0, 0.0, 1.0) {
        return Err(cx.err(line, "<matrix>: must be affine (last row 0 0 0 1)"));
    }
    Ok(m)
}

/// Mitsuba's `look_at`: local +z toward the target, local x = normalize(up x dir).
fn lookat(cx: &Cx, op: &Node) -> Result<Mat4> {
    let get = |k: &str| -> Result<Option<Vec3>> {
        let Some(v) = op.attr(k) else { return Ok(None) };
        match numbers(v).as_deref() {
            Some(&[a, b, c]) => Ok(Some(Vec3::new(a, b, c))),
            _ => Err(cx.err(
                op.attr_line(k),
                format!("<lookat>: {k} '{v}' is not 3 finite numbers"),
            )),
        }
    };
    let (Some(origin), Some(target)) = (get("origin")?, get("target")?) else {
        return Err(cx.err(op.line, "<lookat> needs origin and target"));
    };
    let dir = (target - origin).normalize_or_zero();
    if dir == Vec3::ZERO || !dir.is_finite() {
        return Err(cx.err(op.line, "<lookat>: origin and target coincide"));
    }
    let up = get("up")?.unwrap_or_else(|| coordinate_system(dir));
    let left = up.cross(dir).normalize_or_zero();
    if left == Vec3::ZERO || !left.is_finite() {
        return Err(cx.err(op.line, "<lookat>: up is parallel to the viewing direction"));
    }
    let new_up = dir.cross(left);
    Ok(Mat4::from_cols(
        left.extend(0.0),
        new_up.extend(0.0),
        dir.extend(0.0),
        origin.extend(1.0),
    ))
}

/// The first tangent of Mitsuba's `coordinate_system(n)` (Duff et al. 2017), which
/// Mitsuba uses as `up` when a `<lookat>` has none.
fn coordinate_system(n: Vec3) -> Vec3 {
    let sign = 1.0f32.copysign(n.z);
    let a = -1.0 / (sign + n.z);
    let b = n.x * n.y * a;
    Vec3::new(1.0 + sign * n.x * n.x * a, sign * b, -sign * n.x)
}
