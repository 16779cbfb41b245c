//! Trainee results: the end-of-session text (confusion matrix, accuracy, earlier sessions)
//! and the self-contained HTML report (`arthrosim trainees report`): the learning curve
//! (accuracy per session), grade confusion, response time and force per grade, and links to
//! each session's recording and gap report.

use std::fmt::Write as _;
use std::path::Path;

use crate::db::{CaseRow, SessionRow};

/// Confusion counts: `m[true][answered]`.
pub fn confusion<'a>(cases: impl IntoIterator<Item = &'a CaseRow>, grades: usize) -> Vec<Vec<u32>> {
    let mut m = vec![vec![0u32; grades]; grades];
    for c in cases {
        let (t, a) = (c.true_grade as usize, c.answered_grade as usize);
        if t < grades && a < grades {
            m[t][a] += 1;
        }
    }
    m
}

fn grades_of(sessions: &[SessionRow]) -> usize {
    let from_scales = sessions
        .iter()
        .map(|s| s.grade_scales.len())
        .max()
        .unwrap_or(0);
    let from_cases = sessions
        .iter()
        .flat_map(|s| &s.cases)
        .map(|c| c.true_grade.max(c.answered_grade) as usize + 1)
        .max()
        .unwrap_or(0);
    from_scales.max(from_cases).max(1)
}

/// The text a trainee sees at the end of a session.
pub fn session_text(this: &SessionRow, earlier: &[SessionRow]) -> String {
    let grades = grades_of(std::slice::from_ref(this));
    let m = confusion(&this.cases, grades);
    let mut out = String::new();
    let _ = writeln!(out, "confusion (rows: true grade, columns: your answer)");
    let _ = write!(out, "        ");
    for a in 0..grades {
        let _ = write!(out, " ans {a}");
    }
    let _ = writeln!(out);
    for (t, row) in m.iter().enumerate() {
        let _ = write!(out, "true {t}  ");
        for v in row {
            let _ = write!(out, "{v:>6}");
        }
        let _ = writeln!(out);
    }
    let acc = this.accuracy().unwrap_or(0.0);
    let _ = writeln!(
        out,
        "accuracy {:.0}% ({} of {})",
        acc * 100.0,
        this.correct(),
        this.cases.len()
    );
    let previous: Vec<f64> = earlier.iter().filter_map(|s| s.accuracy()).collect();
    if previous.is_empty() {
        let _ = writeln!(out, "first session of {}", this.trainee);
    } else {
        let mean = previous.iter().sum::<f64>() / previous.len() as f64;
        let last = previous[previous.len() - 1];
        let _ = writeln!(
            out,
            "earlier sessions: {} (mean accuracy {:.0}%, last {:.0}%); this one {:+.0} points vs the mean",
            previous.len(),
            mean * 100.0,
            last * 100.0,
            (acc - mean) * 100.0
        );
    }
    out
}

fn esc(s: &str) -> String {
    s.replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
        .replace('"', "&quot;")
}

fn file_link(path: &str, label: &str) -> String {
    if Path::new(path).exists() {
        format!("<a href=\"file://{}\">{}</a>", esc(path), esc(label))
    } else {
        format!(
            "<span title=\"{}\">{} (missing)</span>",
            esc(path),
            esc(label)
        )
    }
}

fn mean_sd(v: &[f64]) -> Option<(f64, f64)> {
    if v.is_empty() {
        return None;
    }
    let m = v.iter().sum::<f64>() / v.len() as f64;
    let var =
        v.iter().map(|x| (x - m).powi(2)).sum::<f64>() / v.len().max(2).saturating_sub(1) as f64;
    Some((m, var.sqrt()))
}

/// The learning curve as inline SVG: accuracy (0–100%) per session, chance level dashed.
fn learning_curve_svg(sessions: &[SessionRow], grades: usize) -> String {
    let (w, h, pad) = (640.0, 240.0, 36.0);
    let pts: Vec<(f64, f64)> = sessions
        .iter()
        .enumerate()
        .filter_map(|(i, s)| s.accuracy().map(|a| (i as f64, a)))
        .collect();
    let n = sessions.len().max(2) as f64 - 1.0;
    let x = |i: f64| pad + (w - 2.0 * pad) * if n > 0.0 { i / n } else { 0.5 };
    let y = |a: f64| h - pad - (h - 2.0 * pad) * a;
    let mut svg = format!(
        "<svg id=\"learning-curve\" xmlns=\"http://www.w3.org/2000/svg\" width=\"{w}\" height=\"{h}\" viewBox=\"0 0 {w} {h}\">\
         <rect width=\"{w}\" height=\"{h}\" fill=\"#fff\"/>"
    );
    for k in 0..=4 {
        let a = k as f64 / 4.0;
        let _ = write!(
            svg,
            "<line x1=\"{pad}\" x2=\"{}\" y1=\"{y0}\" y2=\"{y0}\" stroke=\"#ddd\"/>\
             <text x=\"4\" y=\"{}\" font-size=\"11\">{:.0}%</text>",
            w - pad,
            y(a) + 4.0,
            a * 100.0,
            y0 = y(a)
        );
    }
    let chance = 1.0 / grades.max(1) as f64;
    let _ = write!(
        svg,
        "<line x1=\"{pad}\" x2=\"{}\" y1=\"{c}\" y2=\"{c}\" stroke=\"#999\" stroke-dasharray=\"4 4\"/>\
         <text x=\"{}\" y=\"{}\" font-size=\"11\" fill=\"#777\">chance</text>",
        w - pad,
        w - pad - 40.0,
        y(chance) - 4.0,
        c = y(chance)
    );
    if pts.len() > 1 {
        let path: Vec<String> = pts
            .iter()
            .map(|(i, a)| format!("{:.1},{:.1}", x(*i), y(*a)))
            .collect();
        let _ = write!(
            svg,
            "<polyline fill=\"none\" stroke=\"#1f6feb\" stroke-width=\"2\" points=\"{}\"/>",
            path.join(" ")
        );
    }
    for (i, a) in &pts {
        let _ = write!(
            svg,
            "<circle cx=\"{:.1}\" cy=\"{:.1}\" r=\"4\" fill=\"#1f6feb\"><title>session {}: {:.0}%</title></circle>",
            x(*i),
            y(*a),
            *i as usize + 1,
            a * 100.0
        );
    }
    svg.push_str("</svg>");
    svg
}

/// The self-contained HTML report of one trainee.
pub fn html(trainee: &str, sessions: &[SessionRow], generated_utc: &str) -> String {
    let grades = grades_of(sessions);
    let all: Vec<&CaseRow> = sessions.iter().flat_map(|s| &s.cases).collect();
    let m = confusion(all.iter().copied(), grades);
    let total = all.len();
    let correct = all
        .iter()
        .filter(|c| c.true_grade == c.answered_grade)
        .count();
    let mut h = String::new();
    let _ = write!(
        h,
        "<!doctype html><html lang=\"en\"><head><meta charset=\"utf-8\"><title>arthrosim — {t}</title>\
         <style>body{{font:14px/1.45 system-ui,sans-serif;margin:24px;color:#1d232a;max-width:980px}}\
         table{{border-collapse:collapse;margin:8px 0 18px}}td,th{{border:1px solid #ccd;padding:4px 9px;text-align:right}}\
         th{{background:#f2f4f7}}td.l,th.l{{text-align:left}}.diag{{background:#e3f4e3;font-weight:600}}\
         h2{{margin-top:28px}}</style></head><body>\
         <h1>Grade training — <span id=\"trainee\">{t}</span></h1>\
         <p>{n} sessions, {total} answered cases, overall accuracy <b id=\"overall-accuracy\">{acc}</b>. Generated {g}.</p>",
        t = esc(trainee),
        n = sessions.len(),
        acc = if total > 0 {
            format!("{:.0}%", 100.0 * correct as f64 / total as f64)
        } else {
            "–".into()
        },
        g = esc(generated_utc),
    );
    h.push_str("<h2>Learning curve: accuracy per session</h2>");
    h.push_str(&learning_curve_svg(sessions, grades));

    h.push_str("<h2>Grade confusion (all sessions)</h2><table id=\"confusion\"><tr><th class=\"l\">true \\ answered</th>");
    for a in 0..grades {
        let _ = write!(h, "<th>grade {a}</th>");
    }
    h.push_str("</tr>");
    for (t, row) in m.iter().enumerate() {
        let _ = write!(h, "<tr><th class=\"l\">grade {t}</th>");
        for (a, v) in row.iter().enumerate() {
            let _ = write!(
                h,
                "<td{}>{v}</td>",
                if a == t { " class=\"diag\"" } else { "" }
            );
        }
        h.push_str("</tr>");
    }
    h.push_str("</table>");

    h.push_str(
        "<h2>Per true grade</h2><table id=\"per-grade\"><tr><th class=\"l\">grade</th><th>cases</th>\
         <th>correct</th><th>response time s (mean ± sd)</th><th>probings (mean)</th>\
         <th>peak normal force N (mean ± sd)</th><th>mean normal force N (mean ± sd)</th></tr>",
    );
    for g in 0..grades {
        let cs: Vec<&&CaseRow> = all.iter().filter(|c| c.true_grade as usize == g).collect();
        let rt: Vec<f64> = cs.iter().map(|c| c.response_time_s).collect();
        let peak: Vec<f64> = cs.iter().filter_map(|c| c.peak_normal_force_n).collect();
        let mean: Vec<f64> = cs.iter().filter_map(|c| c.mean_normal_force_n).collect();
        let pr: Vec<f64> = cs.iter().map(|c| c.probings as f64).collect();
        let f = |v: &[f64], d: usize| {
            mean_sd(v)
                .map(|(m, s)| format!("{m:.d$} ± {s:.d$}"))
                .unwrap_or_else(|| "–".into())
        };
        let _ = write!(
            h,
            "<tr><td class=\"l\">{g}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td></tr>",
            cs.len(),
            cs.iter().filter(|c| c.answered_grade as usize == g).count(),
            f(&rt, 1),
            mean_sd(&pr).map(|(m, _)| format!("{m:.1}")).unwrap_or_else(|| "–".into()),
            f(&peak, 2),
            f(&mean, 2)
        );
    }
    h.push_str("</table>");

    h.push_str(
        "<h2>Sessions</h2><table id=\"sessions\"><tr><th>#</th><th class=\"l\">started (UTC)</th>\
         <th>cases</th><th>correct</th><th>accuracy</th><th class=\"l\">operator</th><th>seed</th>\
         <th class=\"l\">recording</th><th class=\"l\">gap report</th></tr>",
    );
    for (i, s) in sessions.iter().enumerate() {
        let rec = s
            .recording_path
            .as_deref()
            .map(|p| file_link(p, "session.mcap"))
            .unwrap_or_else(|| "–".into());
        let gap = s
            .gap_report_path
            .as_deref()
            .map(|p| {
                if Path::new(p).exists() {
                    file_link(p, "report.html")
                } else {
                    format!(
                        "<code title=\"not made yet\">arthrosim gap {} --out {}</code>",
                        esc(s.recording_path.as_deref().unwrap_or("?")),
                        esc(Path::new(p)
                            .parent()
                            .map(|d| d.display().to_string())
                            .unwrap_or_default()
                            .as_str())
                    )
                }
            })
            .unwrap_or_else(|| "–".into());
        let _ = write!(
            h,
            "<tr><td>{}</td><td class=\"l\">{}</td><td>{}</td><td>{}</td><td>{}</td><td class=\"l\">{}</td><td>{}</td><td class=\"l\">{rec}</td><td class=\"l\">{gap}</td></tr>",
            i + 1,
            esc(&s.started_utc),
            s.cases.len(),
            s.correct(),
            s.accuracy()
                .map(|a| format!("{:.0}%", a * 100.0))
                .unwrap_or_else(|| "–".into()),
            esc(&s.operator),
            s.seed
        );
    }
    h.push_str("</table></body></html>\n");
    h
}

#[cfg(test)]
mod tests {
    use super::*;

    fn row(t: u32, a: u32) -> CaseRow {
        CaseRow {
            case_index: 1,
            true_grade: t,
            modulus_scale: 1.0,
            answered_grade: a,
            answer_source: "page".into(),
            response_time_s: 2.0,
            probings: 2,
            peak_normal_force_n: Some(3.0),
            mean_normal_force_n: Some(1.0),
            started_utc: String::new(),
            answered_utc: String::new(),
        }
    }

    fn session(cases: Vec<CaseRow>) -> SessionRow {
        SessionRow {
            id: 1,
            trainee: "Ada <b>".into(),
            started_utc: "2026".into(),
            finished_utc: None,
            seed: 1,
            case_count: cases.len() as u32,
            grade_scales: vec![1.0, 0.795, 0.59],
            operator: "trainee".into(),
            session_dir: "/nonexistent".into(),
            recording_path: Some("/nonexistent/session.mcap".into()),
            gap_report_path: Some("/nonexistent/gap/report.html".into()),
            cases,
        }
    }

    #[test]
    fn confusion_and_text() {
        let s = session(vec![row(0, 0), row(2, 1), row(2, 2), row(1, 1)]);
        let m = confusion(&s.cases, 3);
        assert_eq!(m, vec![vec![1, 0, 0], vec![0, 1, 0], vec![0, 1, 1]]);
        let text = session_text(&s, &[session(vec![row(0, 1), row(1, 1)])]);
        assert!(text.contains("accuracy 75% (3 of 4)"), "{text}");
        assert!(text.contains("mean accuracy 50%"), "{text}");
    }

    #[test]
    fn html_is_escaped_and_complete() {
        let sessions = vec![
            session(vec![row(0, 0)]),
            session(vec![row(1, 2), row(2, 2)]),
        ];
        let page = html("Ada <b>", &sessions, "now");
        assert!(page.contains("Ada &lt;b&gt;") && !page.contains("Ada <b>"));
        assert!(page.contains("id=\"learning-curve\"") && page.contains("<polyline"));
        assert!(page.contains("overall-accuracy\">67%"));
        assert!(page.contains("session.mcap (missing)"));
    }
}
