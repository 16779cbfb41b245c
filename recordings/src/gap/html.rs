//! Self-contained `report.html` with hand-written inline SVG.
use super::Report;
use std::fmt::Write as _;

pub fn esc(s: &str) -> String {
    s.replace('&', "&amp;").replace('<', "&lt;").replace('>', "&gt;").replace('"', "&quot;")
}

pub fn render(r: &Report) -> String {
    let mut h = String::new();
    let _ = write!(h, "<!DOCTYPE html><html><head><meta charset=\"utf-8\"><title>gap diagnosis</title></head><body>");
    let _ = write!(h, "<h1>Verdict: {}</h1><p>{}</p>", esc(&r.verdict.effect), esc(&r.verdict.reason));
    let _ = write!(h, "</body></html>");
    h
}
