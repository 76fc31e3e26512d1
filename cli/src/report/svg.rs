//! A small SVG chart writer for the demo's and the benchmark's plots: lines,
//! point markers, crosses (infeasible trials), rings (rejected trials),
//! histogram bars and labelled horizontal reference lines (targets) and
//! vertical ones (moments), whose labels are staggered in rows when they
//! would overlap ([`label_rows`]). Pure: a [`Chart`] in, SVG text out.

use std::fmt::Write as _;

/// How one series is drawn.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Mark {
    /// Connected by straight segments (best-so-far, rates over time).
    Line,
    /// A step line: each value holds until the next x.
    Step,
    /// Filled circles (feasible trials).
    Dot,
    /// Crosses (infeasible trials).
    Cross,
    /// Hollow circles (trials whose config failed verification).
    Ring,
    /// Vertical bars from zero; x is the bar's left edge, width from `Chart::bar_width`.
    Bar,
}

/// One named series of (x, y) points.
#[derive(Debug, Clone, PartialEq)]
pub struct Series {
    pub name: String,
    pub mark: Mark,
    pub color: &'static str,
    pub points: Vec<(f64, f64)>,
}

/// A labelled horizontal (y = value) or vertical (x = value) reference line.
#[derive(Debug, Clone, PartialEq)]
pub struct Rule {
    pub label: String,
    pub value: f64,
    pub vertical: bool,
}

/// A whole chart.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Chart {
    pub title: String,
    pub x_label: String,
    pub y_label: String,
    pub series: Vec<Series>,
    pub rules: Vec<Rule>,
    /// Width of `Mark::Bar` bars in x units.
    pub bar_width: f64,
    /// Force y to start at zero (rates, counts).
    pub y_from_zero: bool,
}

const W: f64 = 720.0;
const H: f64 = 420.0;
const LEFT: f64 = 70.0;
const RIGHT: f64 = 170.0;
const TOP: f64 = 40.0;
const BOTTOM: f64 = 50.0;
/// Estimated width of one label character at font-size 12.
const CHAR_W: f64 = 6.5;
/// Height of one row of vertical-rule labels.
const LABEL_ROW: f64 = 14.0;
/// Horizontal gap kept between two labels on the same row.
const LABEL_GAP: f64 = 4.0;

/// The row (0 = top) of each label, given each label's left edge and width
/// in pixels: in left-to-right order each label takes the first row whose
/// labels all end (plus [`LABEL_GAP`]) before it starts, so labels of rules
/// close together never overlap (pure).
pub fn label_rows(spans: &[(f64, f64)]) -> Vec<usize> {
    let mut order: Vec<usize> = (0..spans.len()).collect();
    order.sort_by(|&a, &b| spans[a].0.total_cmp(&spans[b].0));
    // Right end of the last label placed on each row.
    let mut ends: Vec<f64> = Vec::new();
    let mut rows = vec![0; spans.len()];
    for i in order {
        let (left, width) = spans[i];
        let row = match ends.iter().position(|&e| e + LABEL_GAP <= left) {
            Some(r) => r,
            None => {
                ends.push(f64::NEG_INFINITY);
                ends.len() - 1
            }
        };
        ends[row] = left + width;
        rows[i] = row;
    }
    rows
}

/// Colors used by the reports, named for what they show.
pub mod colors {
    pub const CORE: &str = "#1f77b4";
    pub const NON_CORE: &str = "#ff7f0e";
    pub const FEASIBLE: &str = "#2ca02c";
    pub const INFEASIBLE: &str = "#d62728";
    pub const REJECTED: &str = "#9467bd";
    pub const BEST: &str = "#111111";
    pub const OTHER: &str = "#7f7f7f";
}

impl Chart {
    /// The chart as a standalone SVG document.
    pub fn to_svg(&self) -> String {
        let (x0, x1, y0, y1) = self.bounds();
        let sx = |x: f64| LEFT + (x - x0) / (x1 - x0) * (W - LEFT - RIGHT);
        let sy = |y: f64| H - BOTTOM - (y - y0) / (y1 - y0) * (H - TOP - BOTTOM);
        let mut s = String::new();
        let _ = write!(
            s,
            r#"<svg xmlns="http://www.w3.org/2000/svg" width="{W}" height="{H}" viewBox="0 0 {W} {H}" font-family="sans-serif" font-size="12">"#
        );
        s.push_str(r#"<rect width="100%" height="100%" fill="white"/>"#);
        let _ = write!(
            s,
            r#"<text x="{}" y="22" font-size="15" text-anchor="middle">{}</text>"#,
            (LEFT + W - RIGHT) / 2.0,
            esc(&self.title)
        );
        // Axes, ticks and labels.
        let _ = write!(
            s,
            r##"<path d="M{LEFT},{TOP} V{} H{}" fill="none" stroke="#333"/>"##,
            H - BOTTOM,
            W - RIGHT
        );
        for t in ticks(x0, x1) {
            let _ = write!(
                s,
                r##"<line x1="{x}" y1="{}" x2="{x}" y2="{}" stroke="#333"/><text x="{x}" y="{}" text-anchor="middle">{}</text>"##,
                H - BOTTOM,
                H - BOTTOM + 5.0,
                H - BOTTOM + 18.0,
                fmt_tick(t),
                x = sx(t)
            );
        }
        for t in ticks(y0, y1) {
            let _ = write!(
                s,
                r##"<line x1="{}" y1="{y}" x2="{LEFT}" y2="{y}" stroke="#333"/><line x1="{LEFT}" y1="{y}" x2="{}" y2="{y}" stroke="#eee"/><text x="{}" y="{}" text-anchor="end">{}</text>"##,
                LEFT - 5.0,
                W - RIGHT,
                LEFT - 8.0,
                sy(t) + 4.0,
                fmt_tick(t),
                y = sy(t)
            );
        }
        let _ = write!(
            s,
            r#"<text x="{}" y="{}" text-anchor="middle">{}</text>"#,
            (LEFT + W - RIGHT) / 2.0,
            H - 12.0,
            esc(&self.x_label)
        );
        let _ = write!(
            s,
            r#"<text x="18" y="{}" text-anchor="middle" transform="rotate(-90 18 {})">{}</text>"#,
            (TOP + H - BOTTOM) / 2.0,
            (TOP + H - BOTTOM) / 2.0,
            esc(&self.y_label)
        );
        // A vertical rule's label starts right of it, or ends left of it when
        // it would run past the plot into the legend.
        let label_left = |r: &Rule| {
            let (x, width) = (sx(r.value), r.label.chars().count() as f64 * CHAR_W);
            if x + 3.0 + width > W - RIGHT {
                (x - 3.0 - width, width, true)
            } else {
                (x + 3.0, width, false)
            }
        };
        let spans: Vec<(f64, f64)> = self
            .rules
            .iter()
            .filter(|r| r.vertical)
            .map(|r| {
                let (left, width, _) = label_left(r);
                (left, width)
            })
            .collect();
        let mut rows = label_rows(&spans).into_iter();
        for r in &self.rules {
            let (a, b, c, d, tx, ty, anchor) = if r.vertical {
                let x = sx(r.value);
                let row = rows.next().unwrap_or(0) as f64;
                let (left, width, flipped) = label_left(r);
                let (tx, anchor) = if flipped {
                    (left + width, "end")
                } else {
                    (left, "start")
                };
                (
                    x,
                    TOP,
                    x,
                    H - BOTTOM,
                    tx,
                    TOP + 12.0 + row * LABEL_ROW,
                    anchor,
                )
            } else {
                let y = sy(r.value);
                (LEFT, y, W - RIGHT, y, W - RIGHT + 4.0, y + 4.0, "start")
            };
            let _ = write!(
                s,
                r##"<line class="rule" x1="{a}" y1="{b}" x2="{c}" y2="{d}" stroke="#555" stroke-dasharray="5,4"/><text x="{tx}" y="{ty}" text-anchor="{anchor}">{}</text>"##,
                esc(&r.label)
            );
        }
        for (i, se) in self.series.iter().enumerate() {
            let c = se.color;
            match se.mark {
                Mark::Line | Mark::Step => {
                    let mut d = String::new();
                    let mut prev_y = None;
                    for (j, &(x, y)) in se.points.iter().enumerate() {
                        if j == 0 {
                            let _ = write!(d, "M{:.1},{:.1}", sx(x), sy(y));
                        } else {
                            if se.mark == Mark::Step
                                && let Some(py) = prev_y
                            {
                                let _ = write!(d, " L{:.1},{:.1}", sx(x), sy(py));
                            }
                            let _ = write!(d, " L{:.1},{:.1}", sx(x), sy(y));
                        }
                        prev_y = Some(y);
                    }
                    let _ = write!(
                        s,
                        r#"<path class="line" d="{d}" fill="none" stroke="{c}" stroke-width="2"/>"#
                    );
                }
                Mark::Dot => {
                    for &(x, y) in &se.points {
                        let _ = write!(
                            s,
                            r#"<circle class="dot" cx="{:.1}" cy="{:.1}" r="4" fill="{c}"/>"#,
                            sx(x),
                            sy(y)
                        );
                    }
                }
                Mark::Cross => {
                    for &(x, y) in &se.points {
                        let (px, py) = (sx(x), sy(y));
                        let _ = write!(
                            s,
                            r#"<path class="cross" d="M{:.1},{:.1} l8,8 m0,-8 l-8,8" stroke="{c}" stroke-width="2"/>"#,
                            px - 4.0,
                            py - 4.0
                        );
                    }
                }
                Mark::Ring => {
                    for &(x, y) in &se.points {
                        let _ = write!(
                            s,
                            r#"<circle class="ring" cx="{:.1}" cy="{:.1}" r="5" fill="white" stroke="{c}" stroke-width="2"/>"#,
                            sx(x),
                            sy(y)
                        );
                    }
                }
                Mark::Bar => {
                    for &(x, y) in &se.points {
                        let (l, r) = (sx(x), sx(x + self.bar_width));
                        let (t, b) = (sy(y.max(0.0)), sy(0.0_f64.max(y0)));
                        let _ = write!(
                            s,
                            r#"<rect class="bar" x="{:.1}" y="{:.1}" width="{:.1}" height="{:.1}" fill="{c}" fill-opacity="0.6"/>"#,
                            l,
                            t,
                            (r - l - 1.0).max(0.5),
                            (b - t).max(0.0)
                        );
                    }
                }
            }
            // Legend: the series' own mark for point series, a swatch otherwise.
            let ly = TOP + 10.0 + 18.0 * i as f64;
            let (gx, gy) = (W - RIGHT + 16.0, ly - 4.0);
            let _ = match se.mark {
                Mark::Dot => write!(s, r#"<circle cx="{gx}" cy="{gy}" r="4" fill="{c}"/>"#),
                Mark::Ring => write!(
                    s,
                    r#"<circle cx="{gx}" cy="{gy}" r="5" fill="white" stroke="{c}" stroke-width="2"/>"#
                ),
                Mark::Cross => write!(
                    s,
                    r#"<path d="M{},{} l8,8 m0,-8 l-8,8" stroke="{c}" stroke-width="2"/>"#,
                    gx - 4.0,
                    gy - 4.0
                ),
                Mark::Line | Mark::Step | Mark::Bar => write!(
                    s,
                    r#"<rect x="{}" y="{}" width="12" height="12" fill="{c}"/>"#,
                    W - RIGHT + 10.0,
                    ly - 10.0
                ),
            };
            let _ = write!(
                s,
                r#"<text x="{}" y="{}">{}</text>"#,
                W - RIGHT + 28.0,
                ly,
                esc(&se.name)
            );
        }
        s.push_str("</svg>\n");
        s
    }

    /// Data bounds with a margin; never empty.
    fn bounds(&self) -> (f64, f64, f64, f64) {
        let mut xs: Vec<f64> = Vec::new();
        let mut ys: Vec<f64> = Vec::new();
        for se in &self.series {
            for &(x, y) in &se.points {
                if x.is_finite() && y.is_finite() {
                    xs.push(x);
                    ys.push(y);
                    if se.mark == Mark::Bar {
                        xs.push(x + self.bar_width);
                        ys.push(0.0);
                    }
                }
            }
        }
        for r in &self.rules {
            if r.vertical { &mut xs } else { &mut ys }.push(r.value);
        }
        if self.y_from_zero {
            ys.push(0.0);
        }
        let range = |v: &[f64]| {
            let lo = v.iter().copied().fold(f64::INFINITY, f64::min);
            let hi = v.iter().copied().fold(f64::NEG_INFINITY, f64::max);
            if !lo.is_finite() {
                (0.0, 1.0)
            } else if hi - lo < 1e-9 {
                (lo - 0.5, hi + 0.5)
            } else {
                (lo, hi)
            }
        };
        let (x0, x1) = range(&xs);
        let xpad = (x1 - x0) * 0.03;
        let (x0, x1) = (x0 - xpad, x1 + xpad);
        let (y0, y1) = range(&ys);
        let pad = (y1 - y0) * 0.05;
        let y0 = if self.y_from_zero && y0 >= 0.0 {
            0.0
        } else {
            y0 - pad
        };
        (x0, x1, y0, y1 + pad)
    }
}

/// About five round tick values covering [lo, hi].
fn ticks(lo: f64, hi: f64) -> Vec<f64> {
    let raw = (hi - lo) / 5.0;
    let mag = 10f64.powf(raw.log10().floor());
    let step = [1.0, 2.0, 5.0, 10.0]
        .iter()
        .map(|m| m * mag)
        .find(|s| *s >= raw)
        .unwrap_or(10.0 * mag);
    let mut t = (lo / step).ceil() * step;
    let mut out = Vec::new();
    while t <= hi + step * 1e-9 && out.len() < 20 {
        out.push(if t.abs() < step * 1e-9 { 0.0 } else { t });
        t += step;
    }
    out
}

fn fmt_tick(t: f64) -> String {
    if (t - t.round()).abs() < 1e-9 {
        format!("{}", t.round() as i64)
    } else {
        let s = format!("{t:.3}");
        s.trim_end_matches('0').to_owned()
    }
}

/// Escapes text for SVG.
fn esc(s: &str) -> String {
    s.replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
        .replace('"', "&quot;")
}

#[cfg(test)]
mod tests {
    use super::*;

    fn chart() -> Chart {
        Chart {
            title: "trials <1>".into(),
            x_label: "trial".into(),
            y_label: "Hz".into(),
            series: vec![
                Series {
                    name: "feasible".into(),
                    mark: Mark::Dot,
                    color: colors::FEASIBLE,
                    points: vec![(1.0, 3.0), (2.0, 4.0)],
                },
                Series {
                    name: "infeasible".into(),
                    mark: Mark::Cross,
                    color: colors::INFEASIBLE,
                    points: vec![(3.0, 9.0)],
                },
                Series {
                    name: "best".into(),
                    mark: Mark::Step,
                    color: colors::BEST,
                    points: vec![(1.0, 3.0), (2.0, 4.0), (3.0, 4.0)],
                },
            ],
            rules: vec![Rule {
                label: "target".into(),
                value: 5.0,
                vertical: false,
            }],
            ..Chart::default()
        }
    }

    #[test]
    fn draws_one_mark_per_point_and_escapes_text() {
        let svg = chart().to_svg();
        assert_eq!(svg.matches(r#"class="dot""#).count(), 2);
        assert_eq!(svg.matches(r#"class="cross""#).count(), 1);
        assert_eq!(svg.matches(r#"class="line""#).count(), 1);
        assert_eq!(svg.matches(r#"class="rule""#).count(), 1);
        assert!(svg.contains("trials &lt;1&gt;"));
        assert!(svg.starts_with("<svg") && svg.trim_end().ends_with("</svg>"));
    }

    #[test]
    fn higher_values_are_drawn_higher() {
        let svg = chart().to_svg();
        let cy: Vec<f64> = svg
            .split(r#"class="dot" cx=""#)
            .skip(1)
            .map(|p| {
                let p = &p[p.find("cy=\"").unwrap() + 4..];
                p[..p.find('"').unwrap()].parse().unwrap()
            })
            .collect();
        assert!(cy[1] < cy[0], "y=4 must be above y=3: {cy:?}");
    }

    #[test]
    fn a_rule_label_near_the_right_edge_ends_left_of_its_rule() {
        let mut c = chart();
        let label = |x: f64, text: &str| Rule {
            label: text.into(),
            value: x,
            vertical: true,
        };
        // x runs 1..3: a long label at 3 would run past the plot.
        c.rules = vec![label(1.0, "early"), label(3.0, "a long label at the end")];
        let svg = c.to_svg();
        let text_of = |t: &str| {
            let i = svg.find(&format!(">{t}</text>")).unwrap();
            svg[..i].rsplit("<text ").next().unwrap().to_string()
        };
        assert!(text_of("early").contains(r#"text-anchor="start""#), "{svg}");
        let late = text_of("a long label at the end");
        assert!(late.contains(r#"text-anchor="end""#), "{late}");
        let x: f64 = late["x=\"".len()..]
            .split('"')
            .next()
            .unwrap()
            .parse()
            .unwrap();
        assert!(
            x <= W - RIGHT,
            "the flipped label ends at {x}, inside the plot"
        );
    }

    #[test]
    fn close_rule_labels_are_staggered_and_far_ones_share_the_top_row() {
        // Three labels 60 px wide: the 2nd starts 10 px after the 1st (overlaps),
        // the 3rd after both ended; the 4th overlaps only the 3rd.
        let spans = [(100.0, 60.0), (110.0, 60.0), (200.0, 60.0), (230.0, 60.0)];
        assert_eq!(label_rows(&spans), [0, 1, 0, 1]);
        // Input order does not matter: rows follow x.
        assert_eq!(label_rows(&[(110.0, 60.0), (100.0, 60.0)]), [1, 0]);
        // Three labels on top of each other take three rows.
        assert_eq!(label_rows(&[(50.0, 40.0); 3]), [0, 1, 2]);
        // Touching within the gap counts as overlapping; past it, not.
        assert_eq!(label_rows(&[(0.0, 10.0), (12.0, 5.0)]), [0, 1]);
        assert_eq!(label_rows(&[(0.0, 10.0), (14.0, 5.0)]), [0, 0]);
        assert!(label_rows(&[]).is_empty());

        // In the SVG: two moments 0.3 s apart get labels on different rows.
        let mut c = chart();
        c.rules = ["→ terrain-nav", "detected"]
            .iter()
            .zip([2.0, 2.03])
            .map(|(l, v)| Rule {
                label: l.to_string(),
                value: v,
                vertical: true,
            })
            .collect();
        let svg = c.to_svg();
        let y_of = |label: &str| -> f64 {
            let end = svg.find(&format!(">{label}</text>")).unwrap();
            let tag = &svg[svg[..end].rfind("<text").unwrap()..end];
            let p = &tag[tag.find("y=\"").unwrap() + 3..];
            p[..p.find('"').unwrap()].parse().unwrap()
        };
        assert_eq!(y_of("detected") - y_of("→ terrain-nav"), LABEL_ROW);
    }

    #[test]
    fn rings_are_drawn_and_shown_in_the_legend() {
        let mut c = chart();
        c.series.push(Series {
            name: "rejected".into(),
            mark: Mark::Ring,
            color: colors::REJECTED,
            points: vec![(4.0, 6.0)],
        });
        let svg = c.to_svg();
        assert_eq!(svg.matches(r#"class="ring""#).count(), 1);
        // The legend entry draws a ring too (unclassed) right before the name.
        let name = svg.find(">rejected</text>").unwrap();
        let glyph = &svg[svg[..name].rfind("<circle").unwrap()..name];
        assert!(!glyph.contains("class="), "{glyph}");
        assert!(glyph.contains(r#"fill="white" stroke="#), "{glyph}");
    }

    #[test]
    fn ticks_are_round_and_cover_the_range() {
        assert_eq!(ticks(0.0, 10.0), vec![0.0, 2.0, 4.0, 6.0, 8.0, 10.0]);
        let t = ticks(0.13, 0.97);
        assert!(t.first().unwrap() >= &0.13 && t.last().unwrap() <= &0.97);
        assert!(t.len() >= 4);
    }

    #[test]
    fn empty_and_flat_charts_still_render() {
        let mut c = Chart::default();
        assert!(c.to_svg().contains("</svg>"));
        c.series.push(Series {
            name: "flat".into(),
            mark: Mark::Line,
            color: colors::CORE,
            points: vec![(0.0, 2.0), (1.0, 2.0)],
        });
        assert!(!c.to_svg().contains("NaN"));
    }
}
