//! Triangle-surface readers: OBJ (v / f; polygons fan-triangulated) and STL (ASCII and
//! binary; coincident vertices welded).

use std::collections::HashMap;
use std::path::Path;

use nalgebra::Point3;

use super::{MeshError, SurfaceMesh};

/// Reads an OBJ or STL surface, chosen by the file extension.
pub fn read_surface(path: &Path) -> Result<SurfaceMesh, MeshError> {
    let ext = path
        .extension()
        .and_then(|e| e.to_str())
        .map(|e| e.to_ascii_lowercase());
    match ext.as_deref() {
        Some("obj") => read_obj(path),
        Some("stl") => read_stl(path),
        _ => Err(MeshError::Unsupported {
            path: path.into(),
            problem: "surface files must be .obj or .stl".into(),
        }),
    }
}

pub fn read_obj(path: &Path) -> Result<SurfaceMesh, MeshError> {
    let text = std::fs::read_to_string(path).map_err(|e| MeshError::io(path, e))?;
    parse_obj(&text, path)
}

pub fn parse_obj(text: &str, path: &Path) -> Result<SurfaceMesh, MeshError> {
    let mut vertices = Vec::new();
    // Faces as written (1-based or negative), resolved once all vertices are known:
    // OBJ allows faces to refer to vertices defined later only in theory, but negative
    // indices are relative to the vertices read so far, so resolve them on the spot.
    let mut triangles = Vec::new();
    let mut poly = Vec::new();
    for (i, raw) in text.lines().enumerate() {
        let line = i + 1;
        let l = raw.split('#').next().unwrap_or("").trim();
        let mut parts = l.split_whitespace();
        match parts.next() {
            Some("v") => {
                let mut c = [0.0f64; 3];
                for (k, ck) in c.iter_mut().enumerate() {
                    let t = parts
                        .next()
                        .ok_or_else(|| MeshError::parse(path, line, "vertex needs x y z"))?;
                    *ck = t.parse().map_err(|_| {
                        MeshError::parse(
                            path,
                            line,
                            format!("vertex coordinate {k}: `{t}` is not a number"),
                        )
                    })?;
                    if !ck.is_finite() {
                        return Err(MeshError::NonFiniteCoordinate {
                            path: path.into(),
                            line,
                            node: vertices.len() + 1,
                            value: *ck,
                        });
                    }
                }
                vertices.push(Point3::new(c[0], c[1], c[2]));
            }
            Some("f") => {
                poly.clear();
                for t in parts {
                    // `a`, `a/b`, `a//c`, `a/b/c`: the first field is the vertex.
                    let first = t.split('/').next().unwrap_or("");
                    let idx: i64 = first.parse().map_err(|_| {
                        MeshError::parse(path, line, format!("face vertex `{t}` is not an index"))
                    })?;
                    let n = vertices.len() as i64;
                    let resolved = if idx > 0 { idx - 1 } else { n + idx };
                    if idx == 0 || resolved < 0 || resolved >= n {
                        return Err(MeshError::parse(
                            path,
                            line,
                            format!(
                                "face vertex index {idx} is out of range ({n} vertices so far)"
                            ),
                        ));
                    }
                    poly.push(resolved as usize);
                }
                if poly.len() < 3 {
                    return Err(MeshError::parse(
                        path,
                        line,
                        format!("face has {} vertices, needs at least 3", poly.len()),
                    ));
                }
                for k in 1..poly.len() - 1 {
                    triangles.push([poly[0], poly[k], poly[k + 1]]);
                }
            }
            // Normals, texture coordinates, groups, materials, smoothing, lines: not geometry
            // we use.
            _ => {}
        }
    }
    if triangles.is_empty() {
        return Err(MeshError::invalid(path, "no faces (`f` lines)"));
    }
    Ok(SurfaceMesh {
        vertices,
        triangles,
    })
}

pub fn read_stl(path: &Path) -> Result<SurfaceMesh, MeshError> {
    let bytes = std::fs::read(path).map_err(|e| MeshError::io(path, e))?;
    parse_stl(&bytes, path)
}

/// Binary when the size matches the triangle count in the header (some binary files start
/// with "solid" too), otherwise ASCII.
pub fn parse_stl(bytes: &[u8], path: &Path) -> Result<SurfaceMesh, MeshError> {
    if bytes.len() >= 84 {
        let n = u32::from_le_bytes([bytes[80], bytes[81], bytes[82], bytes[83]]) as usize;
        if 84 + 50 * n == bytes.len() {
            return parse_stl_binary(bytes, n, path);
        }
    }
    let starts_solid = bytes
        .iter()
        .skip_while(|b| b.is_ascii_whitespace())
        .take(5)
        .copied()
        .collect::<Vec<u8>>()
        == b"solid";
    if starts_solid {
        let text = std::str::from_utf8(bytes).map_err(|e| MeshError::Unsupported {
            path: path.into(),
            problem: format!("ASCII STL is not valid text: {e}"),
        })?;
        return parse_stl_ascii(text, path);
    }
    if bytes.len() >= 84 {
        let n = u32::from_le_bytes([bytes[80], bytes[81], bytes[82], bytes[83]]) as usize;
        return Err(MeshError::invalid(
            path,
            format!(
                "binary STL header says {n} triangles ({} bytes) but the file has {} bytes",
                84 + 50 * n,
                bytes.len()
            ),
        ));
    }
    Err(MeshError::invalid(
        path,
        "neither ASCII (`solid`) nor binary STL",
    ))
}

struct Welder {
    index: HashMap<[u64; 3], usize>,
    vertices: Vec<Point3<f64>>,
}

impl Welder {
    fn add(&mut self, p: Point3<f64>) -> usize {
        // +0.0 so that -0.0 and 0.0 weld.
        let key = [
            (p.x + 0.0).to_bits(),
            (p.y + 0.0).to_bits(),
            (p.z + 0.0).to_bits(),
        ];
        let next = self.vertices.len();
        *self.index.entry(key).or_insert_with(|| {
            self.vertices.push(p);
            next
        })
    }
}

fn parse_stl_binary(bytes: &[u8], n: usize, path: &Path) -> Result<SurfaceMesh, MeshError> {
    let mut w = Welder {
        index: HashMap::with_capacity(n),
        vertices: Vec::with_capacity(n / 2 + 3),
    };
    let mut triangles = Vec::with_capacity(n);
    for t in 0..n {
        let rec = &bytes[84 + 50 * t..84 + 50 * (t + 1)];
        let f = |k: usize| {
            f32::from_le_bytes([rec[4 * k], rec[4 * k + 1], rec[4 * k + 2], rec[4 * k + 3]]) as f64
        };
        let mut tri = [0usize; 3];
        for (v, slot) in tri.iter_mut().enumerate() {
            let p = Point3::new(f(3 + 3 * v), f(4 + 3 * v), f(5 + 3 * v));
            if let Some(bad) = p.iter().find(|c| !c.is_finite()) {
                return Err(MeshError::invalid(
                    path,
                    format!("triangle {t}: vertex {v} has a non-finite coordinate ({bad})"),
                ));
            }
            *slot = w.add(p);
        }
        triangles.push(tri);
    }
    if triangles.is_empty() {
        return Err(MeshError::invalid(path, "no triangles"));
    }
    Ok(SurfaceMesh {
        vertices: w.vertices,
        triangles,
    })
}

fn parse_stl_ascii(text: &str, path: &Path) -> Result<SurfaceMesh, MeshError> {
    let mut w = Welder {
        index: HashMap::new(),
        vertices: Vec::new(),
    };
    let mut triangles = Vec::new();
    let mut facet: Vec<usize> = Vec::with_capacity(3);
    let mut facet_line = 0;
    for (i, raw) in text.lines().enumerate() {
        let line = i + 1;
        let mut parts = raw.split_whitespace();
        match parts.next() {
            Some("facet") => {
                facet.clear();
                facet_line = line;
            }
            Some("vertex") => {
                let mut c = [0.0f64; 3];
                for ck in c.iter_mut() {
                    let t = parts
                        .next()
                        .ok_or_else(|| MeshError::parse(path, line, "vertex needs x y z"))?;
                    *ck = t.parse().map_err(|_| {
                        MeshError::parse(path, line, format!("`{t}` is not a number"))
                    })?;
                    if !ck.is_finite() {
                        return Err(MeshError::NonFiniteCoordinate {
                            path: path.into(),
                            line,
                            node: w.vertices.len(),
                            value: *ck,
                        });
                    }
                }
                facet.push(w.add(Point3::new(c[0], c[1], c[2])));
            }
            Some("endfacet") => {
                if facet.len() != 3 {
                    return Err(MeshError::parse(
                        path,
                        // An `endfacet` without its `facet` line: point at it.
                        if facet_line == 0 { line } else { facet_line },
                        format!("facet has {} vertices, needs 3", facet.len()),
                    ));
                }
                triangles.push([facet[0], facet[1], facet[2]]);
                facet_line = 0;
            }
            _ => {}
        }
    }
    if triangles.is_empty() {
        return Err(MeshError::invalid(path, "no facets"));
    }
    Ok(SurfaceMesh {
        vertices: w.vertices,
        triangles,
    })
}
