//! Self-contained `report.html` with hand-written inline SVG (no scripts, no external files).
use super::Report;
use std::fmt::Write as _;

pub fn esc(s: &str) -> String {
    s.replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
        .replace('"', "&quot;")
}

fn fmt(v: f64) -> String {
    fmt_value(v)
}

/// A figure of the report, four decimals or, below 0.01 and from 10⁵, four significant
/// figures (a support compliance of 3.3·10⁻⁵ m/N read 0.0000); "–" when not finite.
pub fn fmt_value(v: f64) -> String {
    if !v.is_finite() {
        "–".into()
    } else if v != 0.0 && (v.abs() < 1e-2 || v.abs() >= 1e5) {
        format!("{v:.3e}")
    } else {
        format!("{v:.4}")
    }
}

struct Line<'a> {
    label: &'a str,
    color: &'a str,
    x: &'a [f64],
    y: Vec<f64>,
    dashed: bool,
    dots: bool,
}

fn nice_ticks(lo: f64, hi: f64) -> Vec<f64> {
    let span = (hi - lo).max(1e-12);
    let raw = span / 4.0;
    let mag = 10f64.powf(raw.log10().floor());
    let step = [1.0, 2.0, 5.0, 10.0]
        .iter()
        .map(|m| m * mag)
        .find(|s| *s >= raw)
        .unwrap_or(raw);
    let mut t = (lo / step).ceil() * step;
    let mut v = Vec::new();
    while t <= hi + 1e-12 && v.len() < 12 {
        v.push(t);
        t += step;
    }
    v
}

/// A line plot with axes, ticks and a legend.
fn plot(w: f64, h: f64, title: &str, xlabel: &str, ylabel: &str, lines: &[Line]) -> String {
    let (ml, mr, mt, mb) = (52.0, 10.0, 22.0, 34.0);
    let (mut x0, mut x1, mut y0, mut y1) = (f64::MAX, f64::MIN, f64::MAX, f64::MIN);
    for l in lines {
        for (&x, &y) in l.x.iter().zip(&l.y) {
            if x.is_finite() && y.is_finite() {
                x0 = x0.min(x);
                x1 = x1.max(x);
                y0 = y0.min(y);
                y1 = y1.max(y);
            }
        }
    }
    if x0 > x1 {
        (x0, x1, y0, y1) = (0.0, 1.0, 0.0, 1.0);
    }
    if y1 - y0 < 1e-9 {
        y0 -= 0.5;
        y1 += 0.5;
    }
    let pad = 0.05 * (y1 - y0);
    let (y0, y1) = (y0 - pad, y1 + pad);
    let sx = |x: f64| ml + (x - x0) / (x1 - x0).max(1e-12) * (w - ml - mr);
    let sy = |y: f64| mt + (y1 - y) / (y1 - y0) * (h - mt - mb);
    let mut s = String::new();
    let _ = write!(
        s,
        r#"<svg xmlns="http://www.w3.org/2000/svg" width="{w}" height="{h}" viewBox="0 0 {w} {h}" font-family="sans-serif" font-size="10">"#
    );
    let _ = write!(
        s,
        r##"<rect x="{ml}" y="{mt}" width="{}" height="{}" fill="#fafafa" stroke="#ccc"/>"##,
        w - ml - mr,
        h - mt - mb
    );
    let _ = write!(
        s,
        r#"<text x="{}" y="14" text-anchor="middle" font-size="11" font-weight="bold">{}</text>"#,
        w / 2.0,
        esc(title)
    );
    for t in nice_ticks(x0, x1) {
        let _ = write!(
            s,
            r##"<line x1="{0:.1}" x2="{0:.1}" y1="{1:.1}" y2="{2:.1}" stroke="#e4e4e4"/><text x="{0:.1}" y="{3:.1}" text-anchor="middle">{4}</text>"##,
            sx(t),
            mt,
            h - mb,
            h - mb + 12.0,
            trim(t)
        );
    }
    for t in nice_ticks(y0, y1) {
        let _ = write!(
            s,
            r##"<line x1="{0:.1}" x2="{1:.1}" y1="{2:.1}" y2="{2:.1}" stroke="#e4e4e4"/><text x="{3:.1}" y="{4:.1}" text-anchor="end">{5}</text>"##,
            ml,
            w - mr,
            sy(t),
            ml - 4.0,
            sy(t) + 3.0,
            trim(t)
        );
    }
    let _ = write!(
        s,
        r#"<text x="{}" y="{}" text-anchor="middle">{}</text>"#,
        (ml + w - mr) / 2.0,
        h - 4.0,
        esc(xlabel)
    );
    let _ = write!(
        s,
        r#"<text x="12" y="{}" text-anchor="middle" transform="rotate(-90 12 {})">{}</text>"#,
        (mt + h - mb) / 2.0,
        (mt + h - mb) / 2.0,
        esc(ylabel)
    );
    for (i, l) in lines.iter().enumerate() {
        if l.dots {
            for (&x, &y) in l.x.iter().zip(&l.y) {
                if x.is_finite() && y.is_finite() {
                    let _ = write!(
                        s,
                        r#"<circle cx="{:.1}" cy="{:.1}" r="1.3" fill="{}"/>"#,
                        sx(x),
                        sy(y),
                        l.color
                    );
                }
            }
        } else {
            let pts: Vec<String> =
                l.x.iter()
                    .zip(&l.y)
                    .filter(|(x, y)| x.is_finite() && y.is_finite())
                    .map(|(&x, &y)| format!("{:.1},{:.1}", sx(x), sy(y)))
                    .collect();
            let _ = write!(
                s,
                r#"<polyline fill="none" stroke="{}" stroke-width="1.3" {} points="{}"/>"#,
                l.color,
                if l.dashed {
                    r#"stroke-dasharray="4 2""#
                } else {
                    ""
                },
                pts.join(" ")
            );
        }
        let lx = ml + 8.0 + 110.0 * i as f64;
        let _ = write!(
            s,
            r#"<rect x="{lx:.1}" y="{:.1}" width="10" height="3" fill="{}"/><text x="{:.1}" y="{:.1}">{}</text>"#,
            mt + 6.0,
            l.color,
            lx + 13.0,
            mt + 10.0,
            esc(l.label)
        );
    }
    s.push_str("</svg>");
    s
}

fn trim(v: f64) -> String {
    let s = format!("{v:.3}");
    let s = s.trim_end_matches('0').trim_end_matches('.');
    if s == "-0" {
        "0".into()
    } else {
        s.to_string()
    }
}

fn heat_color(v: f64, max: f64) -> String {
    let f = (v / max.max(1e-12)).clamp(0.0, 1.0);
    // white → orange → dark red
    let r = 255.0 - 90.0 * f;
    let g = 255.0 - 215.0 * f;
    let b = 255.0 - 235.0 * f;
    format!("rgb({:.0},{:.0},{:.0})", r, g, b)
}

fn heatmap(r: &Report) -> String {
    let hm = &r.localisation.heatmap;
    let (cw, ch, ml, mt) = (110.0, 26.0, 90.0, 30.0);
    let w = ml + cw * hm.regions.len() as f64 + 10.0;
    let h = mt + ch * hm.phases.len() as f64 + 10.0;
    let max = hm
        .rmse
        .iter()
        .flatten()
        .flatten()
        .cloned()
        .fold(0.0, f64::max);
    let mut s = String::new();
    let _ = write!(
        s,
        r#"<svg xmlns="http://www.w3.org/2000/svg" width="{w}" height="{h}" font-family="sans-serif" font-size="11">"#
    );
    for (j, reg) in hm.regions.iter().enumerate() {
        let _ = write!(
            s,
            r#"<text x="{:.1}" y="20" text-anchor="middle" font-weight="bold">{}</text>"#,
            ml + cw * (j as f64 + 0.5),
            esc(reg)
        );
    }
    for (i, ph) in hm.phases.iter().enumerate() {
        let y = mt + ch * i as f64;
        let _ = write!(
            s,
            r#"<text x="{:.1}" y="{:.1}" text-anchor="end">{}</text>"#,
            ml - 6.0,
            y + ch / 2.0 + 4.0,
            esc(ph)
        );
        for (j, v) in hm.rmse[i].iter().enumerate() {
            let x = ml + cw * j as f64;
            let (fill, text) = match v {
                Some(v) => (heat_color(*v, max), format!("{v:.3} N")),
                None => ("#eee".to_string(), "–".to_string()),
            };
            let _ = write!(
                s,
                r##"<rect x="{x:.1}" y="{y:.1}" width="{cw}" height="{ch}" fill="{fill}" stroke="#fff"/><text x="{:.1}" y="{:.1}" text-anchor="middle">{text}</text>"##,
                x + cw / 2.0,
                y + ch / 2.0 + 4.0
            );
        }
    }
    s.push_str("</svg>");
    s
}

fn ranking_chart(r: &Report) -> String {
    let n = r.ranking.len().min(20);
    let (bh, ml, w) = (18.0, 170.0, 640.0);
    let h = 30.0 + bh * n as f64 + 20.0;
    let shr: Vec<f64> = r.ranking.iter().take(n).map(|c| c.heldout_shrink).collect();
    let lo = shr.iter().cloned().fold(0.0, f64::min).max(-1.0);
    let hi = shr.iter().cloned().fold(0.0, f64::max).max(0.1);
    let sx = |v: f64| ml + (v.clamp(lo, hi) - lo) / (hi - lo) * (w - ml - 60.0);
    let mut s = String::new();
    let _ = write!(
        s,
        r#"<svg xmlns="http://www.w3.org/2000/svg" width="{w}" height="{h}" font-family="sans-serif" font-size="11">"#
    );
    let _ = write!(
        s,
        r#"<text x="{ml}" y="14" font-weight="bold">held-out RMSE shrink vs baseline (ranked by penalised held-out score)</text>"#
    );
    let x0 = sx(0.0);
    for (i, c) in r.ranking.iter().take(n).enumerate() {
        let y = 26.0 + bh * i as f64;
        let v = c.heldout_shrink;
        let (a, b) = if v >= 0.0 { (x0, sx(v)) } else { (sx(v), x0) };
        let color = if c.effect == r.verdict.effect {
            "#d9531e"
        } else if v >= 0.0 {
            "#4a7fb5"
        } else {
            "#b54a4a"
        };
        let _ = write!(
            s,
            r#"<text x="{:.1}" y="{:.1}" text-anchor="end">{} ({}p)</text>"#,
            ml - 6.0,
            y + 12.0,
            esc(&c.effect),
            c.n_params
        );
        let _ = write!(
            s,
            r#"<rect x="{a:.1}" y="{:.1}" width="{:.1}" height="{:.1}" fill="{color}"/>"#,
            y + 2.0,
            (b - a).max(0.5),
            bh - 5.0
        );
        let _ = write!(
            s,
            r#"<text x="{:.1}" y="{:.1}">{:.1}%</text>"#,
            b.max(x0) + 4.0,
            y + 12.0,
            100.0 * v
        );
    }
    let _ = write!(
        s,
        r##"<line x1="{x0:.1}" x2="{x0:.1}" y1="22" y2="{:.1}" stroke="#333"/>"##,
        h - 16.0
    );
    s.push_str("</svg>");
    s
}

fn group_table(title: &str, g: &[super::metrics::GroupResidual]) -> String {
    let mut s = format!("<h3>{}</h3><table><tr><th>group</th><th>samples</th><th>RMSE N</th><th>normal RMSE N</th><th>tangential RMSE N</th><th>normal bias (sim − meas) N</th></tr>", esc(title));
    for r in g {
        let _ = write!(
            s,
            "<tr><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td></tr>",
            esc(&r.group),
            r.samples,
            fmt(r.rmse),
            fmt(r.rmse_normal),
            fmt(r.rmse_tangential),
            fmt(r.bias_normal)
        );
    }
    s.push_str("</table>");
    s
}

/// The rendering gap: device-rendered vs model force on the session's trajectory.
fn rendering_section(g: &super::session::RenderingGap) -> String {
    let pct = |v: f64| format!("{:.1}%", 100.0 * v);
    let opt = |v: Option<f64>, k: f64, unit: &str| {
        v.map(|v| format!("{:.1} {unit}", k * v))
            .unwrap_or_else(|| "n/a".into())
    };
    let mut h = String::new();
    let _ = write!(
        h,
        "<h2>Rendering gap (device vs model force)</h2><p>session <code>{}</code> · limits: peak {} N, continuous {} N, force scale {} ({})</p><p>{}</p>",
        esc(&g.session),
        fmt(g.limits.peak_force_n),
        fmt(g.limits.continuous_force_n),
        fmt(g.limits.force_scale),
        esc(&g.limits.source),
        esc(&g.summary)
    );
    h.push_str("<table><tr><th>contact ticks</th><th>model mean N</th><th>rendered mean N</th><th>RMSE N</th><th>mean error N</th><th>gain (unclamped)</th><th>coupling N</th><th>limits N</th><th>scaling N</th><th>lag</th><th>at peak</th><th>at continuous limit</th><th>rate-limited</th><th>model above peak</th><th>dominant</th></tr>");
    let _ = write!(
        h,
        "<tr><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{} ({})</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td></tr></table>",
        g.contact_ticks,
        fmt(g.mean_model_force_n),
        fmt(g.mean_rendered_force_n),
        fmt(g.rmse_n),
        fmt(g.mean_error_n),
        fmt(g.force_scale_fit),
        g.force_scale_fit_unclamped.map(fmt).unwrap_or_else(|| "–".into()),
        fmt(g.coupling_rmse_n),
        fmt(g.limiter_rmse_n),
        fmt(g.scaling_rmse_n),
        opt(g.lag_s, 1e3, "ms"),
        pct(g.saturated_peak_fraction),
        pct(g.continuous_limited_fraction),
        pct(g.rate_limited_fraction),
        pct(g.model_above_peak_fraction),
        esc(&g.dominant)
    );
    h.push_str("<table><tr><th>region</th><th>contact ticks</th><th>RMSE N</th><th>mean error N</th><th>gain</th><th>at peak</th><th>clamped</th></tr>");
    for r in &g.by_region {
        let _ = write!(
            h,
            "<tr><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td></tr>",
            esc(&r.group),
            r.ticks,
            fmt(r.rmse_n),
            fmt(r.mean_error_n),
            fmt(r.force_scale_fit),
            pct(r.saturated_fraction),
            pct(r.clamped_fraction)
        );
    }
    h.push_str("</table>");
    let s = &g.series;
    let peak_x = [
        s.t.first().copied().unwrap_or(0.0),
        s.t.last().copied().unwrap_or(1.0),
    ];
    let lines = [
        Line {
            label: "model |f|",
            color: "#4a7fb5",
            x: &s.t,
            y: s.model.clone(),
            dashed: false,
            dots: false,
        },
        Line {
            label: "commanded |f|",
            color: "#999",
            x: &s.t,
            y: s.commanded.clone(),
            dashed: true,
            dots: false,
        },
        Line {
            label: "rendered |f|",
            color: "#d9531e",
            x: &s.t,
            y: s.rendered.clone(),
            dashed: false,
            dots: false,
        },
        Line {
            label: "peak limit",
            color: "#b54a4a",
            x: &peak_x,
            y: vec![g.limits.peak_force_n; 2],
            dashed: true,
            dots: false,
        },
    ];
    h.push_str(&plot(
        1200.0,
        260.0,
        "force magnitude per device tick: physics model vs device",
        "t (s, from the first tick)",
        "|f| (N)",
        &lines,
    ));
    h
}

/// What the nuisances are, and what they were fitted to here.
fn nuisance_paragraph(r: &Report) -> String {
    let mut h = stiffness_paragraph(r);
    if let Some(c) = r.heldout.contact_compliance {
        let _ = write!(
            h,
            "<p><b>Contact nuisance.</b> The force under a probe ball depends on how the \
             contact is discretised far more than the tissue's global response does, so every \
             candidate is also fitted with a compliance in series with the tissue under each \
             probe ball, from 0 to {:.0} µm/N ({:.0} N/mm; one more replay per trial). Fitted \
             to the baseline: <b>{:.2} µm/N</b>{}.</p>",
            1e6 * crate::fit::CONTACT_KNOT * crate::fit::CONTACT_WEIGHT_MAX,
            1e-3 / (crate::fit::CONTACT_KNOT * crate::fit::CONTACT_WEIGHT_MAX),
            1e6 * c,
            if c > 0.0 {
                format!(" ({:.0} N/mm)", 1e-3 / c)
            } else {
                String::new()
            }
        );
    }
    h
}

/// What the stiffness nuisance is, and what it was fitted to here.
fn stiffness_paragraph(r: &Report) -> String {
    match r.heldout.nuisance_scale {
        Some(s) => {
            format!(
                "<p><b>Stiffness nuisance.</b> No model is the specimen: every candidate, and the \
             baseline, is fitted with one more parameter, a scale of the tissue's whole force \
             (modulus and support together) within {:.2}–{:.2}, which no effect is needed for. \
             Fitted to the baseline: <b>×{s:.3}</b>, leaving a held-out RMSE of {} N (the \
             <i>nuisance floor</i>). An effect is named only when it shrinks that floor by at \
             least the minimum shrink, with a per-trial held-out gain of at least two standard \
             errors. <code>modulus</code> and <code>hardening</code> carry their own scale: \
             their fitted scale is the total, and they win only beyond the band.</p>",
                crate::fit::Nuisance::STIFFNESS.lo,
                crate::fit::Nuisance::STIFFNESS.hi,
                fmt(r.heldout.nuisance_rmse)
            ) + &other_nuisances(r)
        }
        None => "<p><b>Stiffness nuisance:</b> off (effects are judged against the replay \
                 as it is).</p>"
            .to_string(),
    }
}

/// The contact and material nuisances fitted to the baseline beside the scale, where on.
fn other_nuisances(r: &Report) -> String {
    let mut h = String::new();
    if let Some(c) = r.heldout.contact_compliance {
        let _ = write!(
            h,
            "<p><b>Contact nuisance.</b> Another contact discretisation differs from the \
             replay by a compliance in series under the probe; fitted beside every candidate \
             up to {} µm/N per probe ball. Fitted to the baseline: <b>{} µm/N</b>.</p>",
            fmt(1e6 * crate::fit::CONTACT_KNOT * crate::fit::CONTACT_WEIGHT_MAX),
            fmt(1e6 * c)
        );
    }
    if let Some(m) = r.heldout.material_weight {
        let _ = write!(
            h,
            "<p><b>Material nuisance.</b> The specimen's constitutive law need not be the \
             replay's (linear corotational): every candidate is fitted with a mixture of it and \
             the stable neo-Hookean law, weight 0 (corotational) to 1 (neo-Hookean). Fitted \
             to the baseline: <b>{m:.2}</b>. Calibration does not write it (a scene has one \
             law).</p>"
        );
    }
    if let (Some(l), Some(se)) = (r.heldout.measured_level, r.heldout.measured_level_se) {
        let (lo, hi) = r
            .heldout
            .level_band
            .unwrap_or_else(|| crate::fit::Nuisance::ALL.level_band());
        let _ = write!(
            h,
            "<p><b>Measured level.</b> The measured normal force over the replay's where the \
             replay presses, pooled over the trials: <b>×{l:.3} ± {se:.3}</b> (between-trial \
             standard error), against the ×{lo:.3}–×{hi:.3} the nuisances may take together. A \
             level beyond that by two standard errors is a stiffness no nuisance explains, and \
             names <code>modulus</code> where it reaches it.</p>"
        );
    }
    h
}

pub fn render(r: &Report) -> String {
    let mut h = String::new();
    h.push_str("<!DOCTYPE html><html><head><meta charset=\"utf-8\"><title>arthrosim gap diagnosis</title><style>");
    h.push_str("body{font-family:sans-serif;margin:24px;max-width:1250px;color:#222}table{border-collapse:collapse;margin:6px 0 14px}td,th{border:1px solid #ccc;padding:3px 8px;font-size:12px;text-align:right}th{background:#f0f0f0}td:first-child{text-align:left}.verdict{background:#fff4e5;border:1px solid #f0b070;padding:10px 16px;border-radius:6px}.trial{display:flex;flex-wrap:wrap;gap:4px}svg{margin:2px}");
    h.push_str("</style></head><body>");
    let _ = write!(h, "<h1>Sim-to-real gap diagnosis</h1><p>input <code>{}</code> · model {} · {} trials, {} samples · noise σ ≈ {:.4} N · lag (measured behind simulated, cross-correlation) {}</p>",
        esc(&r.input), esc(&r.model), r.trials, r.samples, r.noise_sigma,
        r.lag_median_s.map(|l| format!("{:.3} s", l)).unwrap_or_else(|| "n/a".into()));
    let _ = write!(h, "<div class=\"verdict\"><h2>Verdict: {}</h2><p>held-out RMSE shrink <b>{:.1}%</b> ({} → {} N, {}); study metric error (mean normal force in contact) {} → {} N; the verdict's model leaves <b>{:.0}%</b> of the measured force's RMS{}</p><p>{}</p>",
        esc(&r.verdict.effect), 100.0 * r.verdict.heldout_shrink, fmt(r.heldout.baseline_rmse), fmt(r.heldout.winner_rmse), esc(&r.heldout.scheme),
        fmt(r.heldout.baseline_study_error), fmt(r.heldout.winner_study_error), 100.0 * r.verdict.residual_fraction,
        if r.verdict.residual_fraction >= crate::UNEXPLAINED_FRACTION { " (<b>not reproduced</b>: see below)" } else { "" },
        esc(&r.verdict.reason));
    h.push_str(&nuisance_paragraph(r));
    if !r.centres.is_empty() {
        let items: Vec<String> = r.centres.iter().map(|c| esc(c)).collect();
        let _ = write!(
            h,
            "<p><b>Re-simulated at the fitted parameters</b> (the second stage: the \
             interpolation between knots is exact there): {}</p>",
            items.join("; ")
        );
    }
    if r.verdict.indistinguishable.len() > 1 {
        let _ = write!(
            h,
            "<p><b>Indistinguishable on held-out trials:</b> {}</p><ul>",
            esc(&r.verdict.indistinguishable.join(" ~ "))
        );
        for (rival, how) in r.verdict.indistinguishable[1..]
            .iter()
            .zip(&r.verdict.separate_by)
        {
            let _ = write!(
                h,
                "<li>{} vs {}: {}</li>",
                esc(&r.verdict.effect),
                esc(rival),
                esc(how)
            );
        }
        h.push_str("</ul>");
    }
    if !r.verdict.params.is_empty() {
        h.push_str("<table><tr><th>effect</th><th>parameter</th><th>value</th><th>± 1 s.e.</th><th>unit</th></tr>");
        for p in &r.verdict.params {
            let _ = write!(
                h,
                "<tr><td>{}</td><td>{}</td><td>{}{}</td><td>{}</td><td>{}</td></tr>",
                esc(&p.effect),
                esc(&p.name),
                fmt(p.value),
                p.bound_note(),
                fmt(p.std),
                esc(&p.unit)
            );
        }
        h.push_str("</table>");
    }
    h.push_str("</div>");
    let _ = write!(h, "<h2>Where</h2><p>{}</p>", esc(&r.localisation.summary));
    h.push_str("<h3>Baseline residual RMSE, phase × region</h3>");
    h.push_str(&heatmap(r));
    h.push_str(&group_table("by axis", &r.localisation.by_axis));
    h.push_str(&group_table("by phase", &r.localisation.by_phase));
    h.push_str(&group_table("by region", &r.localisation.by_region));
    h.push_str(&group_table("by depth band", &r.localisation.by_depth_band));
    h.push_str("<h2>Which</h2>");
    h.push_str(&ranking_chart(r));
    h.push_str("<table><tr><th>candidate</th><th>params</th><th>fit RMSE N</th><th>held-out RMSE N</th><th>shrink</th><th>shrink over the nuisance floor</th><th>paired gain, SE</th><th>ΔBIC</th><th>study-metric error N</th><th>stiffness nuisance</th><th>contact nuisance µm/N</th><th>material nuisance (neo-Hookean weight)</th><th>fitted (± s.e.)</th></tr>");
    for c in &r.ranking {
        let ps: Vec<String> = c
            .params
            .iter()
            .map(|p| format!("{}={}±{} {}", p.name, fmt(p.value), fmt(p.std), p.unit))
            .collect();
        let nuisance = c
            .nuisance_scale
            .map_or("– (own scale)".to_string(), |s| format!("×{s:.3}"));
        let contact = c
            .contact_compliance
            .map_or("–".to_string(), |v| format!("{:.2}", 1e6 * v));
        let material = c
            .material_weight
            .map_or("–".to_string(), |m| format!("{m:.2}"));
        let _ = write!(h, "<tr><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{:.1}%</td><td>{:.1}%</td><td>{:.1}</td><td>{:.1}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td style=\"text-align:left\">{}</td></tr>",
            esc(&c.effect), c.n_params, fmt(c.fit_rmse), fmt(c.heldout_rmse), 100.0 * c.heldout_shrink, 100.0 * c.floor_shrink, c.floor_gain_z, c.delta_bic, fmt(c.heldout_study_error), esc(&nuisance), esc(&contact), esc(&material), esc(&ps.join(", ")));
    }
    h.push_str("</table>");
    if let Some(g) = &r.rendering_gap {
        h.push_str(&rendering_section(g));
    }
    h.push_str("<h2>Trials: measured vs simulated force (held-out prediction after the winning effect)</h2>");
    h.push_str("<table><tr><th>trial</th><th>region</th><th>RMSE before → after N</th><th>NRMSE before → after</th><th>peak error before → after N</th><th>mean normal force meas / sim / after N</th><th>slope meas / sim N/mm</th><th>hysteresis meas / sim N·mm</th><th>lag s</th></tr>");
    for t in &r.trial_reports {
        let opt = |v: Option<f64>| v.map(fmt).unwrap_or_else(|| "–".into());
        let _ = write!(h, "<tr><td>{}</td><td>{}</td><td>{} → {}</td><td>{} → {}</td><td>{} → {}</td><td>{} / {} / {}</td><td>{} / {}</td><td>{} / {}</td><td>{}</td></tr>",
            esc(&t.name), t.region.map(|r| r.name()).unwrap_or("–"), fmt(t.before.rmse), fmt(t.after.rmse), fmt(t.before.nrmse), fmt(t.after.nrmse),
            fmt(t.before.peak_error), fmt(t.after.peak_error), fmt(t.before.mean_normal_measured), fmt(t.before.mean_normal_simulated), fmt(t.after.mean_normal_simulated),
            opt(t.before.slope_measured), opt(t.before.slope_simulated), fmt(t.before.hysteresis_measured), fmt(t.before.hysteresis_simulated), opt(t.lag_s));
    }
    h.push_str("</table>");
    for t in r.trial_reports.iter().take(30) {
        let _ = write!(
            h,
            "<h3>{} ({})</h3><div class=\"trial\">",
            esc(&t.name),
            t.region
                .map(|r| r.name())
                .unwrap_or(msgs::protocol::UNLABELLED)
        );
        for (k, axis) in ["fx", "fy", "fz"].iter().enumerate() {
            let s = &t.series;
            let lines = [
                Line {
                    label: "measured",
                    color: "#555",
                    x: &s.t,
                    y: s.measured.iter().map(|f| f[k]).collect(),
                    dashed: false,
                    dots: true,
                },
                Line {
                    label: "baseline",
                    color: "#4a7fb5",
                    x: &s.t,
                    y: s.baseline.iter().map(|f| f[k]).collect(),
                    dashed: true,
                    dots: false,
                },
                Line {
                    label: "with effect",
                    color: "#d9531e",
                    x: &s.t,
                    y: s.winner.iter().map(|f| f[k]).collect(),
                    dashed: false,
                    dots: false,
                },
            ];
            h.push_str(&plot(
                400.0,
                210.0,
                &format!("{} {}", t.name, axis),
                "t (s)",
                &format!("{axis} (N)"),
                &lines,
            ));
        }
        h.push_str("</div>");
    }
    h.push_str("</body></html>");
    h
}

#[cfg(test)]
mod tests {
    use super::fmt_value;

    /// Regression: a support compliance of 3.3·10⁻⁵ m/N per node read 0.0000 in the report.
    #[test]
    fn small_and_large_figures_keep_four_significant_figures() {
        assert_eq!(fmt_value(3.2827e-5), "3.283e-5");
        assert_eq!(fmt_value(0.6841), "0.6841");
        assert_eq!(fmt_value(0.0), "0.0000");
        assert_eq!(fmt_value(123456.0), "1.235e5");
        assert_eq!(fmt_value(f64::NAN), "–");
    }
}
