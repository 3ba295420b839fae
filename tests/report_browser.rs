//! `filmscope report` in a real browser: headless Chromium loads the page, the page's own
//! script marks every `<img>` loaded or not, and a screenshot must show something.
//!
//! Chromium is `FILMSCOPE_CHROMIUM` if set, else `chromium` or `chromium-browser` on the
//! PATH. With `FILMSCOPE_REQUIRE_CHROMIUM=1` (set by `.ci/run` once it installed it) a
//! missing browser is a failure; otherwise the test says why it skipped. The page-only
//! checks (self-contained, every image inline) always run.

use crate::common;

use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use common::{estimated_tiny, run_ok, s, tempdir};
use filmscope::report::{base64, IMAGE_CHECK_SCRIPT};

/// Longest a browser run may take.
const BROWSER_TIMEOUT: Duration = Duration::from_secs(120);

fn chromium() -> Result<PathBuf, String> {
    if let Some(p) = std::env::var_os("FILMSCOPE_CHROMIUM") {
        return Ok(PathBuf::from(p));
    }
    for name in ["chromium", "chromium-browser"] {
        let found = Command::new(name)
            .arg("--version")
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .status()
            .is_ok_and(|s| s.success());
        if found {
            return Ok(PathBuf::from(name));
        }
    }
    Err("neither FILMSCOPE_CHROMIUM nor chromium / chromium-browser on the PATH".into())
}

/// Runs headless Chromium on `page` with `extra` arguments; returns its stdout (through a
/// file: a dumped DOM is larger than a pipe holds, and the browser is waited for).
fn run_chromium(browser: &Path, profile: &Path, page: &Path, extra: &[String]) -> String {
    let url = format!("file://{}", page.display());
    let stdout_path = profile.with_extension("stdout");
    let stdout = std::fs::File::create(&stdout_path).expect("stdout file");
    let mut child = Command::new(browser)
        .args([
            "--headless",
            "--no-sandbox",
            "--disable-gpu",
            "--disable-quic",
            "--no-first-run",
            "--disable-background-networking",
            "--disable-component-update",
            "--disable-sync",
            "--hide-scrollbars",
        ])
        .arg(format!("--user-data-dir={}", profile.display()))
        .args(extra)
        .arg(url)
        .stdout(stdout)
        .stderr(Stdio::null())
        .spawn()
        .expect("start chromium");
    let start = Instant::now();
    loop {
        if child.try_wait().expect("wait").is_some() {
            break;
        }
        if start.elapsed() > BROWSER_TIMEOUT {
            let _ = child.kill();
            panic!("chromium took longer than {BROWSER_TIMEOUT:?}");
        }
        std::thread::sleep(Duration::from_millis(50));
    }
    String::from_utf8_lossy(&std::fs::read(&stdout_path).expect("stdout")).into_owned()
}

/// The page as Chromium left it after its scripts ran: (images marked loaded, images
/// marked failed, the check's own counts `data-ok` / `data-failed`).
fn loaded_images(browser: &Path, profile: &Path, page: &Path) -> (usize, usize, String) {
    let dom = run_chromium(
        browser,
        profile,
        page,
        &["--virtual-time-budget=10000".into(), "--dump-dom".into()],
    );
    let ok = dom.matches("data-loaded=\"yes\"").count();
    let failed = dom.matches("data-loaded=\"no\"").count();
    let check = dom
        .split("id=\"image-check\"")
        .nth(1)
        .and_then(|rest| rest.split('>').next())
        .unwrap_or("")
        .to_owned();
    (ok, failed, check)
}

fn report(dir: &Path) -> (PathBuf, String) {
    let (_, est) = estimated_tiny(dir, false);
    let out = dir.join("report.html");
    run_ok(&["report", s(&est), "--out", s(&out)]);
    let html = std::fs::read_to_string(&out).expect("report.html");
    (out, html)
}

#[test]
fn report_is_one_self_contained_file() {
    let dir = tempdir();
    let (_, html) = report(dir.path());
    let imgs = html.matches("<img ").count();
    // Thickness, confidence, thickness sigma, render, comparison, two charts.
    assert_eq!(imgs, 7, "images");
    assert_eq!(html.matches("src=\"data:image/png;base64,").count(), imgs);
    for external in ["http://", "https://", "<link", "src=\"/", "url("] {
        assert!(
            !html.contains(external),
            "page refers outside itself: {external}"
        );
    }
    for section in [
        "Summary",
        "Maps",
        "Appearance",
        "Measured against reproduced",
        "Charts",
    ] {
        assert!(html.contains(&format!("<h2>{section}</h2>")), "{section}");
    }
    assert!(html.contains("p95 dE00"));
}

#[test]
fn every_report_image_loads_in_headless_chromium() {
    let browser = match chromium() {
        Ok(b) => b,
        Err(why) => {
            let required = std::env::var("FILMSCOPE_REQUIRE_CHROMIUM").is_ok_and(|v| v == "1");
            assert!(!required, "FILMSCOPE_REQUIRE_CHROMIUM=1 but {why}");
            eprintln!("skipped: no headless browser ({why})");
            return;
        }
    };
    let dir = tempdir();
    let profile = dir.path().join("profile");
    let (page, html) = report(dir.path());
    let imgs = html.matches("<img ").count();
    let (ok, failed, check) = loaded_images(&browser, &profile, &page);
    assert_eq!((ok, failed), (imgs, 0), "check: {check}");
    assert!(
        check.contains(&format!("data-ok=\"{imgs}\"")) && check.contains("data-failed=\"0\""),
        "{check}"
    );

    let shot = dir.path().join("shot.png");
    run_chromium(
        &browser,
        &profile,
        &page,
        &[
            format!("--screenshot={}", shot.display()),
            "--window-size=1280,2000".into(),
            "--virtual-time-budget=10000".into(),
        ],
    );
    let img = image::open(&shot).expect("screenshot decodes").to_rgb8();
    assert_eq!(img.dimensions(), (1280, 2000));
    let colours: std::collections::HashSet<[u8; 3]> = img.pixels().map(|p| p.0).collect();
    let ink = img.pixels().filter(|p| p.0 != [255, 255, 255]).count();
    let share = ink as f64 / f64::from(img.width() * img.height());
    assert!(
        colours.len() > 200 && share > 0.05,
        "blank screenshot? {} colours, {:.1} % not white",
        colours.len(),
        100.0 * share
    );

    // The check can fail: a page with one good and one broken image.
    let good = std::fs::read(dir.path().join("est").join("thickness_nm.png")).expect("png");
    let broken_page = dir.path().join("broken.html");
    std::fs::write(
        &broken_page,
        format!(
            "<!DOCTYPE html><html><body><p id=\"image-check\"></p><img src=\"data:image/png;base64,{}\"><img src=\"data:image/png;base64,iVBORw0KGgoAAAANSUhEUgAAAAEAAAAB\">{IMAGE_CHECK_SCRIPT}</body></html>",
            base64(&good)
        ),
    )
    .expect("write");
    let (ok, failed, check) = loaded_images(&browser, &profile, &broken_page);
    assert_eq!((ok, failed), (1, 1), "check: {check}");
    assert!(check.contains("data-failed=\"1\""), "{check}");
}
