//! `filmscope report`: one self-contained HTML page for a maps directory: the maps, the
//! render, measured against reproduced, the summary table and charts.
//!
//! Every image is a PNG inlined as a base64 `data:` URI, and the page has no link, script
//! or style from anywhere else, so it opens offline and can be mailed as one file. A small
//! inline script marks each `<img>` with `data-loaded="yes"` or `"no"` once the page has
//! loaded (`complete && naturalWidth > 0`) and writes the count into
//! `#image-check` (`data-ok`, `data-failed`): what the headless-browser test reads.
//!
//! Without the capture (moved, or never known) the page still has the maps, the render and
//! the summary; the comparison is replaced by a note saying why.

use std::fmt::Write as _;
use std::path::Path;

use filmscope_core::colour::Illuminant;

use crate::appearance::compare::{
    compare_stream, median_pixel, open_capture, Comparison, PixelSpectra,
};
use crate::appearance::render::{render_png, RenderOptions};
use crate::appearance::{AppearanceError, SampleFilm};
use crate::export::plot::{render_scatter_panels_png, Scatter, Series};
use crate::export::png::{render_map_png, MapPreview};
use crate::io::{read_cube, write_atomic};
use crate::summary::DispersionRecord;

/// The angle of the report's render, degrees.
pub const REPORT_ANGLE_DEG: f64 = 30.0;

/// What [`write_report`] made.
#[derive(Clone, Debug)]
pub struct Made {
    /// Number of inlined images.
    pub images: usize,
    /// Size of the HTML file, bytes.
    pub bytes: usize,
    /// What was left out, and why.
    pub notes: Vec<String>,
}

/// Standard base64 (RFC 4648, with padding) of `bytes`.
pub fn base64(bytes: &[u8]) -> String {
    use ::base64::Engine as _;
    ::base64::engine::general_purpose::STANDARD.encode(bytes)
}

/// `text` with `&`, `<`, `>` and `"` escaped for HTML.
pub fn escape(text: &str) -> String {
    text.replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
        .replace('"', "&quot;")
}

/// The page under construction.
struct Page {
    html: String,
    images: usize,
}

impl Page {
    fn heading(&mut self, text: &str) {
        let _ = writeln!(self.html, "<h2>{}</h2>", escape(text));
    }

    fn para(&mut self, text: &str) {
        let _ = writeln!(self.html, "<p>{}</p>", escape(text));
    }

    /// The one-band map at `path`, if the run wrote it, as a colour-mapped image (`range`:
    /// the colour bar's ends, `None` from the data) captioned `alt`.
    fn map_if_present(
        &mut self,
        path: &Path,
        title: &str,
        unit: &str,
        range: Option<(f64, f64)>,
        alt: &str,
    ) -> Result<(), AppearanceError> {
        if !path.exists() {
            return Ok(());
        }
        let map = read_cube(path).map_err(|e| AppearanceError::new(path, e))?;
        let png = render_map_png(&MapPreview {
            width: map.samples,
            height: map.lines,
            values: &map.data,
            title,
            unit,
            range,
        })
        .map_err(|e| AppearanceError::new(path, e))?;
        self.image(&png, alt);
        Ok(())
    }

    fn image(&mut self, png: &[u8], alt: &str) {
        self.images += 1;
        let _ = writeln!(
            self.html,
            "<figure><img alt=\"{}\" src=\"data:image/png;base64,{}\"><figcaption>{}</figcaption></figure>",
            escape(alt),
            base64(png),
            escape(alt)
        );
    }

    fn table(&mut self, head: &[&str], rows: &[Vec<String>]) {
        self.html.push_str("<table><tr>");
        for h in head {
            let _ = write!(self.html, "<th>{}</th>", escape(h));
        }
        self.html.push_str("</tr>\n");
        for row in rows {
            self.html.push_str("<tr>");
            for cell in row {
                let _ = write!(self.html, "<td>{}</td>", escape(cell));
            }
            self.html.push_str("</tr>\n");
        }
        self.html.push_str("</table>\n");
    }
}

/// Marks every image as loaded or not once the page has loaded.
pub const IMAGE_CHECK_SCRIPT: &str = "<script>\nwindow.addEventListener('load', function () {\n  var imgs = document.images, ok = 0;\n  for (var i = 0; i < imgs.length; i++) {\n    var good = imgs[i].complete && imgs[i].naturalWidth > 0;\n    imgs[i].setAttribute('data-loaded', good ? 'yes' : 'no');\n    if (good) ok++;\n  }\n  var s = document.getElementById('image-check');\n  s.setAttribute('data-ok', ok);\n  s.setAttribute('data-failed', imgs.length - ok);\n  s.textContent = ok + ' of ' + imgs.length + ' images loaded';\n});\n</script>\n";

const STYLE: &str = "<style>body{font-family:sans-serif;max-width:1200px;margin:1em auto;color:#222}table{border-collapse:collapse;margin:0.5em 0}td,th{border:1px solid #bbb;padding:2px 8px;text-align:left}figure{margin:1em 0}img{max-width:100%;image-rendering:pixelated}#image-check{color:#888;font-size:small}</style>\n";

/// `x ± sigma` with as many decimals as the sigma's second significant digit needs (at
/// least four), or `x` alone without a sigma.
fn with_sigma(x: Option<f64>, sigma: Option<f64>) -> String {
    let Some(x) = x else { return "-".into() };
    match sigma.filter(|s| s.is_finite() && *s > 0.0) {
        Some(s) => {
            let decimals = (1.0 - s.log10().floor()).clamp(4.0, 12.0) as usize;
            format!("{x:.decimals$} ± {s:.decimals$}")
        }
        None => format!("{x:.4}"),
    }
}

/// The index model in words, with its coefficients.
fn dispersion_words(d: Option<&DispersionRecord>) -> String {
    match d {
        None => "-".into(),
        Some(DispersionRecord::Constant { n }) => format!("constant, n = {n:.4}"),
        Some(DispersionRecord::Cauchy { a, b_um2, c_um4 }) => format!(
            "Cauchy, n = A + B/λ² + C/λ⁴: A = {a:.4}, B = {b_um2:.5} µm², C = {c_um4:.6} µm⁴"
        ),
        Some(DispersionRecord::Sellmeier { a, b, c_um }) => {
            let terms: Vec<String> = b
                .iter()
                .zip(c_um)
                .map(|(b, c)| format!("{b:.4} λ²/(λ² − {c:.4}²)"))
                .collect();
            format!("Sellmeier, n² = {a:.4} + {} (λ in µm)", terms.join(" + "))
        }
        Some(DispersionRecord::Table { rows }) => {
            format!("a table of n and k, {} rows", rows.len())
        }
    }
}

fn summary_rows(film: &SampleFilm) -> Vec<Vec<String>> {
    let s = &film.summary;
    let num = |x: Option<f64>| x.map_or("-".into(), |x| format!("{x:.2}"));
    let mut rows = vec![
        vec!["method".into(), s.method.name().into()],
        vec!["source".into(), s.source.clone()],
        vec![
            "refractive index at 550 nm".into(),
            with_sigma(s.refractive_index, s.refractive_index_sigma),
        ],
        vec!["index model".into(), s.index_model.clone()],
        vec![
            "dispersion".into(),
            dispersion_words(s.dispersion.as_ref().map(|d| &d.model)),
        ],
        vec![
            "substrate / ambient index".into(),
            format!(
                "{:.4} / {:.4}",
                film.substrate_550(),
                film.stack.ambient_index
            ),
        ],
        vec![
            "polarisation".into(),
            film.stack.polarization.name().to_owned(),
        ],
    ];
    let t = &s.thickness_nm;
    for (k, v) in [
        ("mean", t.mean),
        ("median", t.median),
        ("std", t.std),
        ("min", t.min),
        ("max", t.max),
    ] {
        rows.push(vec![format!("thickness {k}, nm"), num(v)]);
    }
    let sigma = &s.thickness_sigma_nm;
    for (k, v) in [
        ("median", sigma.stats.median),
        ("p90", sigma.p90),
        ("max", sigma.stats.max),
    ] {
        rows.push(vec![
            format!("thickness 1-sigma {k}, nm"),
            v.map_or("-".into(), |x| format!("{x:.3}")),
        ]);
    }
    rows.push(vec![
        "valid fraction".into(),
        format!("{:.2} %", 100.0 * s.valid_fraction),
    ]);
    rows.push(vec![
        "size, px".into(),
        format!("{} x {}", film.width, film.height),
    ]);
    let angles: Vec<String> = s.angles_deg.iter().map(|a| format!("{a}")).collect();
    rows.push(vec!["angles, deg".into(), angles.join(", ")]);
    rows.push(vec!["bands".into(), s.bands.to_string()]);
    rows.push(vec![
        "run time, s".into(),
        format!("{:.2}", s.timing.seconds),
    ]);
    for (name, n) in s.flags.iter().filter(|(_, n)| **n > 0) {
        rows.push(vec![format!("flag {name}, px"), n.to_string()]);
    }
    rows
}

/// The charts of a comparison: CIEDE2000 per angle, and the spectra of the pixel of
/// median thickness measured against the model at the first and last angle.
fn comparison_charts(cmp: &Comparison) -> Result<Vec<u8>, AppearanceError> {
    let mean: Vec<(f64, f64)> = cmp
        .angles
        .iter()
        .map(|a| (a.incidence_deg, a.stats.mean))
        .collect();
    let p95: Vec<(f64, f64)> = cmp
        .angles
        .iter()
        .map(|a| (a.incidence_deg, a.stats.p95))
        .collect();
    let series = [
        Series {
            name: "mean",
            points: &mean,
            labels: None,
        },
        Series {
            name: "95th percentile",
            points: &p95,
            labels: None,
        },
    ];
    let panels = [Scatter {
        title: "CIEDE2000, measured vs reproduced",
        x_label: "incidence angle, degrees",
        y_label: "dE00",
        x_log: false,
        y_log: false,
        series: &series,
        pareto: false,
    }];
    render_scatter_panels_png("colour difference per angle", &panels).map_err(AppearanceError::from)
}

/// Reflectance against wavelength of the pixel of median thickness, measured and
/// modelled, at the first and last captured angle; `None` without such a pixel.
fn spectra_chart(
    film: &SampleFilm,
    spectra: &[PixelSpectra],
) -> Result<Option<Vec<u8>>, AppearanceError> {
    let Some((pixel, d)) = median_pixel(film).and_then(|p| Some((p, film.thickness_at(p)?))) else {
        return Ok(None);
    };
    if spectra.is_empty() {
        return Ok(None);
    }
    let ends = [spectra.first(), spectra.last()];
    let names: Vec<[String; 2]> = ends
        .iter()
        .flatten()
        .map(|p| {
            [
                format!("measured {:.0}°", p.incidence_deg),
                format!("model {:.0}°", p.incidence_deg),
            ]
        })
        .collect();
    let series: Vec<Series> = ends
        .iter()
        .flatten()
        .zip(&names)
        .flat_map(|(p, [m, f])| {
            [
                Series {
                    name: m,
                    points: &p.measured,
                    labels: None,
                },
                Series {
                    name: f,
                    points: &p.model,
                    labels: None,
                },
            ]
        })
        .collect();
    let title = format!(
        "pixel ({}, {}), d = {d:.1} nm",
        pixel % film.width,
        pixel / film.width
    );
    let panels = [Scatter {
        title: &title,
        x_label: "wavelength, nm",
        y_label: "reflectance",
        x_log: false,
        y_log: false,
        series: &series,
        pareto: false,
    }];
    render_scatter_panels_png("measured and modelled spectra", &panels)
        .map(Some)
        .map_err(AppearanceError::from)
}

/// Writes the report of the maps directory `run` to `out` (atomically).
pub fn write_report(
    run: &Path,
    out: &Path,
    capture: Option<&Path>,
) -> Result<Made, AppearanceError> {
    let film = SampleFilm::load(run, capture)?;
    let mut notes = Vec::new();
    let mut page = Page {
        html: String::new(),
        images: 0,
    };
    let title = format!("filmscope report: {}", run.display());
    let _ = write!(
        page.html,
        "<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\"><title>{}</title>\n{STYLE}</head><body>\n<h1>{}</h1>\n<p id=\"image-check\">images not checked yet</p>\n",
        escape(&title),
        escape(&title)
    );

    page.heading("Summary");
    page.table(&["quantity", "value"], &summary_rows(&film));
    page.maps(run, &film)?;
    page.appearance(&film)?;
    page.heading("Measured against reproduced");
    let cmp = match film.capture.as_deref() {
        None => Err("the capture is unknown (pass --capture)".to_owned()),
        Some(cap) => open_capture(cap)
            .and_then(|mut source| {
                compare_stream(
                    &film,
                    &mut source,
                    Illuminant::D65,
                    median_pixel(&film),
                    None,
                )
            })
            .map_err(|e| e.to_string()),
    };
    match cmp {
        Ok((cmp, spectra)) => page.comparison(&film, &cmp, &spectra)?,
        Err(why) => {
            page.para(&format!("No comparison: {why}."));
            notes.push(format!("no comparison in the report: {why}"));
        }
    }
    page.html.push_str(IMAGE_CHECK_SCRIPT);
    page.html.push_str("</body></html>\n");
    write_atomic(out, page.html.as_bytes()).map_err(|e| AppearanceError::new(out, e))?;
    Ok(Made {
        images: page.images,
        bytes: page.html.len(),
        notes,
    })
}

impl Page {
    /// The maps section: the thickness map, and the confidence and thickness uncertainty
    /// maps the run wrote.
    fn maps(&mut self, run: &Path, film: &SampleFilm) -> Result<(), AppearanceError> {
        self.heading("Maps");
        let thickness = render_map_png(&MapPreview {
            width: film.width,
            height: film.height,
            values: &film.thickness_nm,
            title: &format!("thickness, {}", film.describe()),
            unit: "nm",
            range: None,
        })
        .map_err(|e| AppearanceError::new(run, e))?;
        self.image(&thickness, "thickness map (nm; grey: no reliable estimate)");
        self.map_if_present(
            &run.join("confidence.hdr"),
            "confidence",
            "",
            Some((0.0, 1.0)),
            "confidence map (0..1)",
        )?;
        let limit = film.summary.thickness_sigma_nm.imprecise_above;
        self.map_if_present(
            &run.join("thickness_sigma_nm.hdr"),
            "thickness 1-sigma from each pixel's fit",
            "nm",
            None,
            &format!(
                "thickness uncertainty map (nm, 1-sigma of each pixel's own fit and the index's uncertainty; a pixel above {limit} nm is flagged imprecise)"
            ),
        )
    }

    /// The appearance section: the render at [`REPORT_ANGLE_DEG`] under D65.
    fn appearance(&mut self, film: &SampleFilm) -> Result<(), AppearanceError> {
        self.heading("Appearance");
        let (render, info) = render_png(
            film,
            &RenderOptions {
                incidence_deg: REPORT_ANGLE_DEG,
                illuminant: Illuminant::D65,
                exposure: None,
            },
        )?;
        self.image(
            &render,
            &format!(
                "render at {REPORT_ANGLE_DEG}° under D65 (exposure x{:.1}), angle strip 0-70°",
                info.exposure
            ),
        );
        Ok(())
    }

    /// The comparison `cmp` (under its heading): how it was made, its image, its table
    /// per angle, and the charts (with the median pixel's `spectra`).
    fn comparison(
        &mut self,
        film: &SampleFilm,
        cmp: &Comparison,
        spectra: &[PixelSpectra],
    ) -> Result<(), AppearanceError> {
        let (lo, hi) = cmp.colorimetry.range_nm();
        self.para(&format!(
            "Both the measured reflectance and the film model averaged over the same passbands are summed to XYZ over {lo:.0}-{hi:.0} nm only (D65, CIE 1931 2°, white = perfect reflector over the same range); CIEDE2000 per pixel. All angles: mean {:.3}, p95 {:.3} over {} pixels.",
            cmp.overall.mean, cmp.overall.p95, cmp.overall.pixels
        ));
        self.image(
            &cmp.to_png()?,
            "measured | reproduced | CIEDE2000, per captured angle",
        );
        let rows: Vec<Vec<String>> = cmp
            .angles
            .iter()
            .map(|a| {
                vec![
                    format!("{:.1}", a.incidence_deg),
                    a.stats.pixels.to_string(),
                    format!("{:.3}", a.stats.mean),
                    format!("{:.3}", a.stats.median),
                    format!("{:.3}", a.stats.p95),
                ]
            })
            .collect();
        self.table(
            &[
                "angle, deg",
                "pixels",
                "mean dE00",
                "median dE00",
                "p95 dE00",
            ],
            &rows,
        );
        self.heading("Charts");
        self.image(&comparison_charts(cmp)?, "CIEDE2000 per captured angle");
        if let Some(png) = spectra_chart(film, spectra)? {
            self.image(
                &png,
                "the pixel of median thickness: measured band reflectance and the model, first and last angle",
            );
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn base64_matches_rfc_4648_vectors() {
        for (input, want) in [
            ("", ""),
            ("f", "Zg=="),
            ("fo", "Zm8="),
            ("foo", "Zm9v"),
            ("foob", "Zm9vYg=="),
            ("fooba", "Zm9vYmE="),
            ("foobar", "Zm9vYmFy"),
        ] {
            assert_eq!(base64(input.as_bytes()), want);
        }
    }

    #[test]
    fn escape_neutralises_markup() {
        assert_eq!(
            escape("<a href=\"x\">&</a>"),
            "&lt;a href=&quot;x&quot;&gt;&amp;&lt;/a&gt;"
        );
    }
}
