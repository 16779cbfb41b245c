//! The one CSV input path of arthrosim: the device replay trajectory (haptic node), the gap
//! diagnosis' trial files and the force–displacement table all go through [`parse`], which
//! reads with the `csv` crate and applies one set of rules:
//!
//! - the first non-blank, non-`#` line is the header; it must name every wanted column (any
//!   order, extra columns ignored);
//! - every row has as many fields as the header; fields are trimmed;
//! - every wanted value is a number and finite ([`Spec::dropouts`] names the only columns
//!   where a non-finite value is kept, as a recorded sensor dropout);
//! - the ordering column ([`Spec::order`]) increases (strictly or not) from row to row;
//! - a quaternion ([`Spec::quaternion`]) has unit norm (within [`UNIT_QUATERNION_TOLERANCE`])
//!   and is returned normalised;
//! - every error is a [`CsvError`] naming the file and the line.

use std::path::{Path, PathBuf};

/// How far a quaternion's norm may be from 1 (rounding in a written file), dimensionless.
pub const UNIT_QUATERNION_TOLERANCE: f64 = 1e-3;

/// A CSV input error: the file, the 1-based line and the problem.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("{}:{line}: {problem}", file.display())]
pub struct CsvError {
    pub file: PathBuf,
    pub line: usize,
    pub problem: String,
}

/// How a column must be ordered from row to row.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Order {
    /// Each value is larger than the previous one (time).
    Increasing,
    /// Each value is at least the previous one (a displacement table).
    NonDecreasing,
}

/// What to read from a file.
#[derive(Debug, Clone, Copy)]
pub struct Spec<'a> {
    /// The wanted columns; row values are returned in this order.
    pub columns: &'a [&'a str],
    /// Index (into `columns`) of the ordering column, how it is ordered, and its name in
    /// errors (e.g. "time").
    pub order: Option<(usize, Order, &'a str)>,
    /// Indices (into `columns`) of a quaternion `[x, y, z, w]`.
    pub quaternion: Option<[usize; 4]>,
    /// Indices (into `columns`) whose non-finite values are kept (a recorded dropout); a
    /// quaternion with a non-finite component is then kept as recorded, too.
    pub dropouts: &'a [usize],
    /// Largest allowed |value| of a column: `(index into columns, bound)`. Checked as each
    /// row is read, before the ordering, so a value beyond the bound is named as such even
    /// where it also breaks the ordering (1e15 s + 1 ms rounds to 1e15 s).
    pub magnitude: &'a [(usize, f64)],
}

impl<'a> Spec<'a> {
    /// All columns finite, no ordering, no quaternion.
    pub const fn columns(columns: &'a [&'a str]) -> Spec<'a> {
        Spec {
            columns,
            order: None,
            quaternion: None,
            dropouts: &[],
            magnitude: &[],
        }
    }
}

/// The rows read: `values` holds `columns.len()` values per row, in [`Spec::columns`] order.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Table {
    /// Line of the header.
    pub header_line: usize,
    stride: usize,
    values: Vec<f64>,
    lines: Vec<usize>,
}

impl Table {
    pub fn len(&self) -> usize {
        self.lines.len()
    }

    pub fn is_empty(&self) -> bool {
        self.lines.is_empty()
    }

    /// The values of row `i`, in [`Spec::columns`] order.
    pub fn row(&self, i: usize) -> &[f64] {
        &self.values[i * self.stride..(i + 1) * self.stride]
    }

    /// The file line of row `i`.
    pub fn line(&self, i: usize) -> usize {
        self.lines[i]
    }

    pub fn rows(&self) -> impl Iterator<Item = &[f64]> {
        self.values.chunks_exact(self.stride.max(1))
    }
}

/// Reads `path` and parses it (see [`parse`]); an unreadable file is an error at line 0.
pub fn read(path: &Path, spec: &Spec) -> Result<Table, CsvError> {
    let text = std::fs::read_to_string(path).map_err(|e| CsvError {
        file: path.to_path_buf(),
        line: 0,
        problem: format!("cannot read: {e}"),
    })?;
    parse(&text, path, spec)
}

/// Parses CSV `text` under the module's rules; `file` names the file in errors.
pub fn parse(text: &str, file: &Path, spec: &Spec) -> Result<Table, CsvError> {
    let err = |line: usize, problem: String| CsvError {
        file: file.to_path_buf(),
        line,
        problem,
    };
    let mut reader = csv::ReaderBuilder::new()
        .has_headers(false)
        .flexible(true)
        .comment(Some(b'#'))
        .trim(csv::Trim::All)
        .from_reader(text.as_bytes());
    let mut records = reader.records().filter(|r| match r {
        // A whitespace-only line is one empty field: skip it like a blank line.
        Ok(rec) => !(rec.len() == 1 && rec[0].is_empty()),
        Err(_) => true,
    });
    // The csv crate's line counter skips comment and blank lines, and a record's byte offset
    // is where the skipped lines before it start: count lines here from the offset, past
    // the blank and comment lines.
    let line_starts: Vec<usize> = std::iter::once(0)
        .chain(text.match_indices('\n').map(|(i, _)| i + 1))
        .collect();
    let line_at = |p: Option<&csv::Position>| {
        let Some(p) = p else { return 0 };
        let mut line = line_starts.partition_point(|&s| s <= p.byte() as usize);
        while line < line_starts.len() {
            let start = line_starts[line - 1];
            let end = line_starts[line];
            let l = text[start..end].trim();
            if l.is_empty() || l.starts_with('#') {
                line += 1;
            } else {
                break;
            }
        }
        line
    };
    let record_line = |e: &csv::Error| line_at(e.position());
    let line_of = |r: &csv::StringRecord| line_at(r.position());

    let header = match records.next() {
        None => {
            return Err(err(
                1,
                format!("empty file (expected columns {})", spec.columns.join(",")),
            ))
        }
        Some(Err(e)) => return Err(err(record_line(&e), e.to_string())),
        Some(Ok(h)) => h,
    };
    let header_line = line_of(&header);
    let names: Vec<&str> = header.iter().collect();
    let mut index = Vec::with_capacity(spec.columns.len());
    let mut missing = Vec::new();
    for col in spec.columns {
        match names.iter().position(|n| n == col) {
            Some(i) => index.push(i),
            None => missing.push(*col),
        }
    }
    if !missing.is_empty() {
        return Err(err(
            header_line,
            format!("missing column(s) {}", missing.join(", ")),
        ));
    }

    let stride = spec.columns.len();
    let mut table = Table {
        header_line,
        stride,
        values: Vec::new(),
        lines: Vec::new(),
    };
    let mut row = vec![0.0f64; stride];
    for rec in records {
        let rec = rec.map_err(|e| err(record_line(&e), e.to_string()))?;
        let line = line_of(&rec);
        if rec.len() != names.len() {
            return Err(err(
                line,
                format!("{} columns, header has {}", rec.len(), names.len()),
            ));
        }
        for (k, (&i, col)) in index.iter().zip(spec.columns).enumerate() {
            let c = &rec[i];
            let x: f64 = c
                .parse()
                .map_err(|_| err(line, format!("column {col}: not a number: {c:?}")))?;
            if !x.is_finite() && !spec.dropouts.contains(&k) {
                return Err(err(line, format!("column {col}: non-finite value {c}")));
            }
            row[k] = x;
        }
        for &(k, bound) in spec.magnitude {
            if row[k].abs() > bound {
                return Err(err(
                    line,
                    format!(
                        "column {}: {} is out of range; |value| ≤ {bound}",
                        spec.columns[k], row[k]
                    ),
                ));
            }
        }
        if let Some((k, order, name)) = spec.order {
            if let Some(&last) = table.lines.len().checked_sub(1).map(|r| &table.row(r)[k]) {
                let v = row[k];
                match order {
                    Order::Increasing if v <= last => {
                        return Err(err(
                            line,
                            format!("{name} not increasing: {v} after {last}"),
                        ))
                    }
                    Order::NonDecreasing if v < last => {
                        return Err(err(line, format!("{name} decreasing: {v} after {last}")))
                    }
                    _ => {}
                }
            }
        }
        if let Some(q) = spec.quaternion {
            if q.iter().all(|&k| row[k].is_finite()) {
                let norm = q.iter().map(|&k| row[k] * row[k]).sum::<f64>().sqrt();
                if norm < 1e-6 {
                    return Err(err(line, "zero quaternion".into()));
                }
                if (norm - 1.0).abs() > UNIT_QUATERNION_TOLERANCE {
                    return Err(err(
                        line,
                        format!(
                            "quaternion norm {norm} is not 1 (a rotation is a unit quaternion)"
                        ),
                    ));
                }
                for &k in &q {
                    row[k] /= norm;
                }
            }
        }
        table.values.extend_from_slice(&row);
        table.lines.push(line);
    }
    Ok(table)
}

#[cfg(test)]
mod tests {
    use super::*;

    const POSE: [&str; 5] = ["t_s", "qx", "qy", "qz", "qw"];

    fn spec(dropouts: &'static [usize]) -> Spec<'static> {
        Spec {
            columns: &POSE,
            order: Some((0, Order::Increasing, "time")),
            quaternion: Some([1, 2, 3, 4]),
            dropouts,
            magnitude: &[],
        }
    }

    #[test]
    fn reads_columns_in_any_order_skipping_comments_and_blank_lines() {
        let text =
            "# a comment\n\nqw, extra ,t_s,qx,qy,qz\n1,9,0,0,0,0\n  \n1.0000001,9,0.5,0,0,0\n";
        let t = parse(text, Path::new("a.csv"), &spec(&[])).unwrap();
        assert_eq!(t.header_line, 3);
        assert_eq!(t.len(), 2);
        assert_eq!(t.row(1)[0], 0.5);
        assert_eq!(t.line(1), 6);
        assert!((t.row(1)[4] - 1.0).abs() < 1e-15, "normalised");
    }

    #[test]
    fn every_rule_names_file_and_line() {
        let p = Path::new("dir/b.csv");
        let cases = [
            ("", 1, "empty file"),
            ("t_s,qx,qy,qw\n", 1, "missing column(s) qz"),
            ("t_s,qx,qy,qz,qw\n0,0,0,0\n", 2, "4 columns, header has 5"),
            (
                "t_s,qx,qy,qz,qw\n0,0,zz,0,1\n",
                2,
                "column qy: not a number: \"zz\"",
            ),
            (
                "t_s,qx,qy,qz,qw\n0,0,NaN,0,1\n",
                2,
                "column qy: non-finite value NaN",
            ),
            (
                "t_s,qx,qy,qz,qw\n0,0,0,0,1\n\n0,0,0,0,1\n",
                4,
                "time not increasing: 0 after 0",
            ),
            ("t_s,qx,qy,qz,qw\n0,0,0,0,0\n", 2, "zero quaternion"),
            (
                "t_s,qx,qy,qz,qw\n0,0,0,0,0.9\n",
                2,
                "quaternion norm 0.9 is not 1",
            ),
        ];
        for (text, line, problem) in cases {
            let e = parse(text, p, &spec(&[])).unwrap_err();
            assert_eq!(e.line, line, "{e}");
            let msg = e.to_string();
            assert!(msg.starts_with(&format!("dir/b.csv:{line}: ")), "{msg}");
            assert!(msg.contains(problem), "{msg} lacks {problem}");
        }
        let nd = Spec {
            order: Some((0, Order::NonDecreasing, "displacement")),
            ..Spec::columns(&["d"])
        };
        assert!(parse("d\n1\n1\n", p, &nd).is_ok());
        let e = parse("d\n1\n0.5\n", p, &nd).unwrap_err();
        assert_eq!(
            (e.line, e.problem.as_str()),
            (3, "displacement decreasing: 0.5 after 1")
        );
    }

    #[test]
    fn dropout_columns_keep_non_finite_values_as_recorded() {
        let text = "t_s,qx,qy,qz,qw\n0,NaN,0,0,1\n";
        let t = parse(text, Path::new("c.csv"), &spec(&[1, 2, 3, 4])).unwrap();
        assert!(t.row(0)[1].is_nan());
        // Time is never a dropout column here.
        let e = parse(
            "t_s,qx,qy,qz,qw\nNaN,0,0,0,1\n",
            Path::new("c.csv"),
            &spec(&[1]),
        );
        assert!(e.unwrap_err().problem.contains("non-finite"));
    }

    #[test]
    fn reads_a_file_and_names_an_unreadable_one() {
        let e = read(Path::new("/nonexistent/x.csv"), &spec(&[])).unwrap_err();
        assert!(
            e.to_string()
                .starts_with("/nonexistent/x.csv:0: cannot read"),
            "{e}"
        );
    }
}
