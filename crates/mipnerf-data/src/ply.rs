//! The positions of a PLY point cloud: the `x`, `y`, `z` of its `vertex` element, from an ASCII
//! or binary (little- or big-endian) file, every other property read past. nerfstudio writes its
//! capture's COLMAP points so (`sparse_pc.ply`, ASCII); the process step takes the photos' depth
//! bounds from them ([`crate::nerfstudio`]).

use std::path::Path;

use crate::DataError;

/// The bytes of one value of a PLY scalar type (both the old names and the sized ones).
fn type_size(name: &str) -> Option<usize> {
    Some(match name {
        "char" | "uchar" | "int8" | "uint8" => 1,
        "short" | "ushort" | "int16" | "uint16" => 2,
        "int" | "uint" | "int32" | "uint32" | "float" | "float32" => 4,
        "double" | "float64" => 8,
        _ => return None,
    })
}

/// How the body is stored.
#[derive(Clone, Copy, PartialEq, Eq)]
enum Format {
    Ascii,
    Little,
    Big,
}

/// One element of the header: its name, count, and its scalar properties' `(name, type)`
/// (`None` for an element with a list property, which only ASCII files can read past).
struct Element {
    name: String,
    count: usize,
    properties: Option<Vec<(String, String)>>,
}

/// The points of the PLY file `path`, in file order.
///
/// # Errors
/// [`DataError`] naming the file: not a PLY file, no `vertex` element or no `x`, `y`, `z` in
/// it, a list property in a binary file's element before or in the vertices, a body shorter than
/// its header declares, a value that is not a number, or a point that is not finite.
pub fn read_points(path: &Path) -> Result<Vec<[f64; 3]>, DataError> {
    let bytes =
        mipnerf_core::io::read_regular(path, mipnerf_core::io::cap::POINT_CLOUD).map_err(|e| DataError::io(path, e))?;
    let bad = |problem: String| DataError::invalid(path, problem);
    let (header, body) = split_header(&bytes).map_err(bad)?;
    let (format, elements) = parse_header(header).map_err(bad)?;
    let Some(v) = elements.iter().position(|e| e.name == "vertex") else {
        return Err(bad("no \"vertex\" element: the file holds no points".into()));
    };
    let properties = elements[v]
        .properties
        .as_ref()
        .ok_or_else(|| bad("the vertex element has a list property; points have x, y, z and scalars".into()))?;
    let column = |axis: &str| {
        properties
            .iter()
            .position(|(n, _)| n == axis)
            .ok_or_else(|| bad(format!("the vertex element has no property \"{axis}\"")))
    };
    let xyz = [column("x")?, column("y")?, column("z")?];
    let count = elements[v].count;
    // A point is at least one byte of body per property; more points than that is a lie.
    if count.saturating_mul(properties.len()) > bytes.len() {
        return Err(bad(format!("declares {count} points, more than its {} bytes can hold", bytes.len())));
    }
    mipnerf_core::memory::check((count as u64).saturating_mul(24), &format!("reading {count} points")).map_err(&bad)?;
    let vertices = Vertices { before: &elements[..v], properties, xyz, count };
    let points = if format == Format::Ascii {
        ascii_points(&bytes[body..], vertices).map_err(bad)?
    } else {
        binary_points(&bytes, body, vertices, format == Format::Little).map_err(bad)?
    };
    if let Some(i) = points.iter().position(|p| !p.iter().all(|x| x.is_finite())) {
        return Err(bad(format!("point {i} is not finite: {:?}", points[i])));
    }
    Ok(points)
}

/// The header's text and where the body starts (after the `end_header` line's newline).
fn split_header(bytes: &[u8]) -> Result<(&str, usize), String> {
    let end = b"end_header";
    let header_end = bytes
        .windows(end.len())
        .position(|w| w == end)
        .ok_or_else(|| "not a PLY file: no \"end_header\" line".to_owned())?;
    let header = std::str::from_utf8(&bytes[..header_end]).map_err(|_| "the PLY header is not text".to_owned())?;
    let mut body = header_end + end.len();
    while body < bytes.len() && bytes[body] != b'\n' {
        body += 1;
    }
    Ok((header, (body + 1).min(bytes.len())))
}

/// The header's format and elements (an element with a list property has `properties` None).
fn parse_header(header: &str) -> Result<(Format, Vec<Element>), String> {
    let bad = |problem: String| problem;
    let mut lines = header.lines();
    if lines.next().map(str::trim) != Some("ply") {
        return Err(bad("not a PLY file: it does not begin with \"ply\"".into()));
    }
    let (mut format, mut elements) = (None, Vec::<Element>::new());
    for (k, line) in lines.enumerate() {
        let words: Vec<&str> = line.split_whitespace().collect();
        let at = || format!("header line {}", k + 2);
        match words.as_slice() {
            ["format", f, _] => {
                format = Some(match *f {
                    "ascii" => Format::Ascii,
                    "binary_little_endian" => Format::Little,
                    "binary_big_endian" => Format::Big,
                    other => return Err(bad(format!("{}: unknown format {other:?}", at()))),
                });
            }
            ["element", name, count] => {
                let count = count.parse().map_err(|_| bad(format!("{}: element count {count:?}", at())))?;
                elements.push(Element { name: (*name).to_owned(), count, properties: Some(Vec::new()) });
            }
            ["property", "list", ..] => {
                let e = elements.last_mut().ok_or_else(|| bad(format!("{}: a property before any element", at())))?;
                e.properties = None;
            }
            ["property", ty, name] => {
                if type_size(ty).is_none() {
                    return Err(bad(format!("{}: unknown property type {ty:?}", at())));
                }
                let e = elements.last_mut().ok_or_else(|| bad(format!("{}: a property before any element", at())))?;
                if let Some(p) = &mut e.properties {
                    p.push(((*name).to_owned(), (*ty).to_owned()));
                }
            }
            ["comment", ..] | ["obj_info", ..] | [] => {}
            _ => return Err(bad(format!("{}: not a PLY header line: {line:?}", at()))),
        }
    }
    let format = format.ok_or_else(|| bad("the PLY header has no \"format\" line".into()))?;
    Ok((format, elements))
}

/// The vertex element as the body stores it: the elements before it, its scalar properties
/// (name, type), the columns of x, y and z, and its count.
#[derive(Clone, Copy)]
struct Vertices<'a> {
    before: &'a [Element],
    properties: &'a [(String, String)],
    xyz: [usize; 3],
    count: usize,
}

/// The points of an ASCII body: a row a vertex, after the rows of the elements before.
fn ascii_points(body: &[u8], vertices: Vertices<'_>) -> Result<Vec<[f64; 3]>, String> {
    let bad = |problem: String| problem;
    let Vertices { before, xyz, count, .. } = vertices;
    let mut points = Vec::with_capacity(count);
    let text = std::str::from_utf8(body).map_err(|_| bad("the ASCII body is not text".into()))?;
    // Saturating: counts are the header's word, and a lie must not overflow.
    let skip = before.iter().fold(0usize, |n, e| n.saturating_add(e.count));
    let mut rows = text.lines().filter(|l| !l.trim().is_empty()).skip(skip);
    for i in 0..count {
        let row = rows.next().ok_or_else(|| bad(format!("ends after {i} of its {count} points")))?;
        let words: Vec<&str> = row.split_whitespace().collect();
        let mut p = [0.0; 3];
        for (a, &c) in xyz.iter().enumerate() {
            p[a] = words
                .get(c)
                .and_then(|w| w.parse::<f64>().ok())
                .ok_or_else(|| bad(format!("point {i}: {row:?} has no number in column {c}")))?;
        }
        points.push(p);
    }
    Ok(points)
}

/// The points of a binary body: fixed-size rows, after the rows of the elements before.
fn binary_points(bytes: &[u8], body: usize, vertices: Vertices<'_>, little: bool) -> Result<Vec<[f64; 3]>, String> {
    let bad = |problem: String| problem;
    let Vertices { before, properties, xyz, count } = vertices;
    let mut points = Vec::with_capacity(count);
    let mut at = body;
    for e in before {
        let p = e.properties.as_ref().ok_or_else(|| {
            bad(format!(
                "the element \"{}\" before the vertices has a list property, which a binary file cannot skip",
                e.name
            ))
        })?;
        let size: usize = p.iter().filter_map(|(_, t)| type_size(t)).sum();
        at = at.saturating_add(size.saturating_mul(e.count));
    }
    let sizes: Vec<usize> = properties.iter().filter_map(|(_, t)| type_size(t)).collect();
    let stride: usize = sizes.iter().sum();
    let offsets: Vec<usize> = sizes.iter().scan(0, |o, s| Some(std::mem::replace(o, *o + s))).collect();
    if at.saturating_add(stride.saturating_mul(count)) > bytes.len() {
        return Err(bad(format!("its body is shorter than the {count} points its header declares")));
    }
    for i in 0..count {
        let mut p = [0.0; 3];
        for (a, &c) in xyz.iter().enumerate() {
            let start = at + i * stride + offsets[c];
            p[a] = scalar(&bytes[start..start + sizes[c]], &properties[c].1, little);
        }
        points.push(p);
    }
    Ok(points)
}

/// One binary value of type `ty` (its size checked by the caller) as a number.
fn scalar(b: &[u8], ty: &str, little: bool) -> f64 {
    macro_rules! read {
        ($t:ty) => {{
            let a = b.try_into().unwrap_or_default();
            f64::from(if little { <$t>::from_le_bytes(a) } else { <$t>::from_be_bytes(a) })
        }};
    }
    match ty {
        "char" | "int8" => read!(i8),
        "uchar" | "uint8" => read!(u8),
        "short" | "int16" => read!(i16),
        "ushort" | "uint16" => read!(u16),
        "int" | "int32" => read!(i32),
        "uint" | "uint32" => read!(u32),
        "float" | "float32" => read!(f32),
        _ => read!(f64),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn write(name: &str, bytes: &[u8]) -> std::path::PathBuf {
        let dir = std::env::temp_dir().join(format!("mipnerf-ply-read-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join(name);
        std::fs::write(&path, bytes).unwrap();
        path
    }

    /// nerfstudio's form (ASCII, float x y z and uchar colours), with a face element after the
    /// vertices and a comment.
    #[test]
    fn ascii_points_are_read_past_their_colours() {
        let text = "ply\nformat ascii 1.0\ncomment x\nelement vertex 2\nproperty float x\nproperty float y\n\
                    property float z\nproperty uint8 red\nproperty uint8 green\nproperty uint8 blue\n\
                    element face 1\nproperty list uchar int vertex_indices\nend_header\n\
                    -2.290099 3.370441 -1.932370 182 162 125\n6.5 -1 8e2 1 2 3\n3 0 1 0\n";
        let points = read_points(&write("a.ply", text.as_bytes())).unwrap();
        assert_eq!(points, vec![[-2.290099, 3.370441, -1.932370], [6.5, -1.0, 800.0]]);
    }

    /// A little-endian file of float positions and uchar colours (the form `mipnerf export`
    /// writes), and a big-endian double file with the coordinates in another order and an
    /// element before the vertices.
    #[test]
    fn binary_points_are_read_in_either_byte_order() {
        let mut little = b"ply\nformat binary_little_endian 1.0\ncomment made by mipnerf export\nelement vertex 2\n\
                           property float x\nproperty float y\nproperty float z\nproperty uchar red\n\
                           property uchar green\nproperty uchar blue\nend_header\n"
            .to_vec();
        for (p, c) in [([1.5f32, -2.0, 3.25], [1u8, 2, 3]), ([0.0, 7.0, -0.5], [4, 5, 6])] {
            p.iter().for_each(|x| little.extend_from_slice(&x.to_le_bytes()));
            little.extend_from_slice(&c);
        }
        assert_eq!(read_points(&write("l.ply", &little)).unwrap(), vec![[1.5, -2.0, 3.25], [0.0, 7.0, -0.5]]);

        let mut big = b"ply\nformat binary_big_endian 1.0\nelement camera 1\nproperty short id\n\
                        element vertex 1\nproperty double z\nproperty uchar k\nproperty double x\nproperty double y\nend_header\n"
            .to_vec();
        big.extend_from_slice(&7i16.to_be_bytes());
        big.extend_from_slice(&3.0f64.to_be_bytes());
        big.push(9);
        big.extend_from_slice(&1.0f64.to_be_bytes());
        big.extend_from_slice(&2.0f64.to_be_bytes());
        assert_eq!(read_points(&write("b.ply", &big)).unwrap(), vec![[1.0, 2.0, 3.0]]);
    }

    #[test]
    fn malformed_files_are_refused_naming_the_problem() {
        let head = "ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\nproperty float y\nproperty float z\nend_header\n";
        let cases = [
            ("not a ply", "no \"end_header\""),
            ("obj\nend_header\n", "does not begin with \"ply\""),
            ("ply\nelement vertex 1\nproperty float x\nend_header\n", "no \"format\" line"),
            (
                "ply\nformat ascii 1.0\nelement face 1\nproperty list uchar int i\nend_header\n3 0 1 2\n",
                "no \"vertex\" element",
            ),
            (
                "ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\nend_header\n1 2\n",
                "no property \"z\"",
            ),
            (&format!("{head}1 2 3\n"), "ends after 1 of its 2 points"),
            (&format!("{head}1 2 3\n4 five 6\n"), "point 1"),
            (&format!("{head}1 2 3\n4 nan 6\n"), "point 1 is not finite"),
            (
                "ply\nformat ascii 1.0\nelement vertex 99999999\nproperty float x\nproperty float y\nproperty float z\nend_header\n1 2 3\n",
                "more than its",
            ),
            (
                "ply\nformat binary_little_endian 1.0\nelement vertex 2\nproperty float x\nproperty float y\nproperty float z\nend_header\n\0\0\0\0\0\0\0\0\0\0\0\0\0\0",
                "shorter than",
            ),
            ("ply\nformat ascii 1.0\nelement vertex 1\nproperty half x\nend_header\n", "unknown property type"),
            (
                // Elements before the vertices whose counts sum past usize::MAX.
                "ply\nformat ascii 1.0\nelement a 18446744073709551615\nproperty float q\nelement b 18446744073709551615\nproperty float q\nelement vertex 1\nproperty float x\nproperty float y\nproperty float z\nend_header\n1 2 3\n",
                "ends after 0 of its 1 points",
            ),
        ];
        for (k, (text, want)) in cases.iter().enumerate() {
            let path = write(&format!("bad{k}.ply"), text.as_bytes());
            let err = read_points(&path).unwrap_err().to_string();
            assert!(err.contains(want) && err.contains(&format!("bad{k}.ply")), "case {k}: {err}");
        }
    }
}
