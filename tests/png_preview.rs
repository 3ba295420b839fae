//! PNG previews: the rendered bytes are decoded again with the `image` crate and checked
//! pixel by pixel (map colours, no-data grey, legend, sizes), and bad input must fail
//! with a one-line error instead of panicking.

#![cfg(feature = "std")]

use std::collections::HashSet;
use std::error::Error;
use std::path::PathBuf;

use filmscope::export::colormap::{viridis, NO_DATA};
use filmscope::export::png::{
    render_map_png, render_rgb_png, write_map_png, write_rgb_png, MapPreview, PreviewError,
    MIN_MAP_WIDTH,
};
use image::RgbImage;

type TestResult = Result<(), Box<dyn Error>>;

const W: usize = 48;
const H: usize = 32;
/// The documented upscale factor for a 48-pixel-wide map: ceil(384 / 48).
const K: usize = 8;

/// A 48x32 thickness map: a ramp from 380 to 420 nm along x, a NaN block at the top
/// left (rows 0..4, columns 0..6), the global minimum 300 nm at (10, 20) and the global
/// maximum 500 nm at (40, 5).
fn ramp_map() -> Vec<f32> {
    let mut v = Vec::with_capacity(W * H);
    for y in 0..H {
        for x in 0..W {
            let value = if x < 6 && y < 4 {
                f32::NAN
            } else {
                380.0 + 40.0 * x as f32 / (W - 1) as f32
            };
            v.push(value);
        }
    }
    v[20 * W + 10] = 300.0;
    v[5 * W + 40] = 500.0;
    v
}

fn preview<'a>(values: &'a [f32], title: &'a str) -> MapPreview<'a> {
    MapPreview {
        width: W,
        height: H,
        values,
        title,
        unit: "nm",
        range: None,
    }
}

fn decode(png: &[u8]) -> Result<RgbImage, Box<dyn Error>> {
    Ok(image::load_from_memory(png)?.to_rgb8())
}

fn px(img: &RgbImage, x: usize, y: usize) -> [u8; 3] {
    img.get_pixel(x as u32, y as u32).0
}

/// The top-left corner of the map: in raster order the first grey pixel that starts a
/// whole upscaled block of grey, the NaN block at map pixel (0, 0) (the title's
/// anti-aliased text has grey pixels, never a block of them).
fn map_origin(img: &RgbImage) -> Option<(usize, usize)> {
    let grey =
        |x: u32, y: u32| x < img.width() && y < img.height() && img.get_pixel(x, y).0 == NO_DATA;
    let k = K as u32;
    img.enumerate_pixels()
        .find(|&(x, y, _)| (0..k).all(|d| (0..k).all(|e| grey(x + d, y + e))))
        .map(|(x, y, _)| (x as usize, y as usize))
}

/// The centre of map pixel `(x, y)` in the image.
fn centre(origin: (usize, usize), x: usize, y: usize) -> (usize, usize) {
    (origin.0 + x * K + K / 2, origin.1 + y * K + K / 2)
}

#[test]
fn map_is_upscaled_and_coloured_with_viridis() -> TestResult {
    let values = ramp_map();
    let img = decode(&render_map_png(&preview(&values, "Thickness"))?)?;
    let origin = map_origin(&img).ok_or("no grey NaN block found")?;

    // The map alone is 48 * 8 = 384 px wide; the legend comes on top of that.
    assert_eq!(W * K, MIN_MAP_WIDTH);
    assert!(
        img.width() as usize >= origin.0 + W * K + 100,
        "{}",
        img.width()
    );
    assert!(
        img.height() as usize >= origin.1 + H * K,
        "{}",
        img.height()
    );

    // The whole NaN block is grey, up to its last upscaled pixel, and not beyond.
    for y in 0..4 * K {
        for x in 0..6 * K {
            assert_eq!(px(&img, origin.0 + x, origin.1 + y), NO_DATA, "({x}, {y})");
        }
    }
    assert_ne!(px(&img, origin.0 + 6 * K, origin.1), NO_DATA);
    assert_ne!(px(&img, origin.0, origin.1 + 4 * K), NO_DATA);

    // Below the 1st percentile / above the 99th: the ends of the colour map, over the
    // whole upscaled block.
    for (mx, my, t) in [(10, 20, 0.0), (40, 5, 1.0)] {
        for dy in 0..K {
            for dx in 0..K {
                let p = px(&img, origin.0 + mx * K + dx, origin.1 + my * K + dy);
                assert_eq!(p, viridis(t), "map pixel ({mx}, {my}) + ({dx}, {dy})");
            }
        }
    }

    // The ramp runs from dark (left) to bright (right).
    let (lx, ly) = centre(origin, 8, 16);
    let (rx, ry) = centre(origin, W - 2, 16);
    let lum = |p: [u8; 3]| p.iter().map(|&c| u32::from(c)).sum::<u32>();
    assert!(lum(px(&img, lx, ly)) < lum(px(&img, rx, ry)));
    Ok(())
}

#[test]
fn given_range_maps_its_ends_to_the_ends_of_viridis() -> TestResult {
    let values = ramp_map();
    let p = MapPreview {
        range: Some((380.0, 420.0)),
        ..preview(&values, "Thickness")
    };
    let img = decode(&render_map_png(&p)?)?;
    let origin = map_origin(&img).ok_or("no grey NaN block found")?;
    let (x0, y0) = centre(origin, 0, 10); // 380 nm
    let (x1, y1) = centre(origin, W - 1, 10); // 420 nm
    assert_eq!(px(&img, x0, y0), viridis(0.0));
    assert_eq!(px(&img, x1, y1), viridis(1.0));
    let (xm, ym) = centre(origin, 20, 10);
    let t = (380.0 + 40.0 * 20.0 / 47.0 - 380.0) / 40.0;
    let expected = viridis(t);
    let got = px(&img, xm, ym);
    for (g, e) in got.iter().zip(expected) {
        assert!(g.abs_diff(e) <= 1, "{got:?} vs {expected:?}");
    }
    Ok(())
}

#[test]
fn legend_has_a_colour_bar_and_text() -> TestResult {
    let values = ramp_map();
    let img = decode(&render_map_png(&preview(&values, "Thickness"))?)?;
    let origin = map_origin(&img).ok_or("no grey NaN block found")?;
    let legend_x = origin.0 + W * K + 2;
    let mut colours = HashSet::new();
    let mut dark = 0usize;
    for y in 0..img.height() as usize {
        for x in legend_x..img.width() as usize {
            let p = px(&img, x, y);
            colours.insert(p);
            if p.iter().all(|&c| c < 40) {
                dark += 1;
            }
        }
    }
    // The bar alone holds a couple of hundred viridis shades.
    assert!(colours.len() > 100, "{} colours", colours.len());
    assert!(colours.contains(&viridis(0.0)) && colours.contains(&viridis(1.0)));
    // Text pixels (tick labels and the note).
    assert!(dark > 200, "{dark} text pixels");
    // The title is above the map: dark pixels in the band above it.
    let title_dark = (0..origin.1)
        .flat_map(|y| (0..img.width() as usize).map(move |x| (x, y)))
        .filter(|&(x, y)| px(&img, x, y).iter().all(|&c| c < 40))
        .count();
    assert!(title_dark > 50, "{title_dark} title pixels");
    Ok(())
}

#[test]
fn all_nan_map_still_renders() -> TestResult {
    let values = vec![f32::NAN; W * H];
    let img = decode(&render_map_png(&preview(&values, "Nothing found"))?)?;
    let origin = map_origin(&img).ok_or("no grey map found")?;
    assert!(img.width() as usize >= origin.0 + W * K);
    // Mostly grey, with the "no valid pixels" box in the middle.
    let mut grey = 0usize;
    let mut dark = 0usize;
    for y in 0..H * K {
        for x in 0..W * K {
            let p = px(&img, origin.0 + x, origin.1 + y);
            if p == NO_DATA {
                grey += 1;
            } else if p.iter().all(|&c| c < 40) {
                dark += 1;
            }
        }
    }
    assert!(grey > W * K * H * K * 3 / 4, "{grey} grey pixels");
    assert!(dark > 50, "{dark} text pixels on the map");
    // Nothing viridis anywhere.
    assert!(!img
        .pixels()
        .any(|p| p.0 == viridis(0.0) || p.0 == viridis(1.0)));

    // With a given range, the legend is drawn anyway.
    let p = MapPreview {
        range: Some((1.0, 2.0)),
        ..preview(&values, "Nothing found")
    };
    let img = decode(&render_map_png(&p)?)?;
    assert!(img.pixels().any(|p| p.0 == viridis(1.0)));
    Ok(())
}

#[test]
fn infinities_flat_maps_and_odd_sizes_do_not_panic() -> TestResult {
    let mut values = ramp_map();
    values[W + 20] = f32::INFINITY;
    values[2 * W + 20] = f32::NEG_INFINITY;
    values[3 * W + 20] = f32::MAX;
    values[3 * W + 21] = f32::MIN;
    let img = decode(&render_map_png(&preview(&values, "inf"))?)?;
    let origin = map_origin(&img).ok_or("no grey NaN block found")?;
    // Infinities carry no estimate: grey. f32::MAX and MIN are clamped to the ends.
    let (x, y) = centre(origin, 20, 1);
    assert_eq!(px(&img, x, y), NO_DATA);
    let (x, y) = centre(origin, 20, 2);
    assert_eq!(px(&img, x, y), NO_DATA);
    let (x, y) = centre(origin, 20, 3);
    assert_eq!(px(&img, x, y), viridis(1.0));
    let (x, y) = centre(origin, 21, 3);
    assert_eq!(px(&img, x, y), viridis(0.0));

    // Only infinities and NaN.
    let values = [f32::INFINITY, f32::NEG_INFINITY, f32::NAN, f32::INFINITY];
    let p = MapPreview {
        width: 2,
        height: 2,
        values: &values,
        title: "",
        unit: "",
        range: None,
    };
    decode(&render_map_png(&p)?)?;

    // A flat map, a single pixel, a 1000-pixel-wide strip, a tall thin column, a long
    // non-ASCII title and an empty unit.
    let flat = [250.0f32; 16];
    let one = [1.5f32];
    let strip: Vec<f32> = (0..1000).map(|i| i as f32).collect();
    let column: Vec<f32> = (0..3000).map(|i| (i as f32).sin()).collect();
    let title = "Ünïcödé title that is far too long to fit above the map at any size ".repeat(4);
    for (w, h, v) in [
        (4, 4, &flat[..]),
        (1, 1, &one[..]),
        (1000, 1, &strip[..]),
        (1, 3000, &column[..]),
    ] {
        let p = MapPreview {
            width: w,
            height: h,
            values: v,
            title: &title,
            unit: "",
            range: None,
        };
        let img = decode(&render_map_png(&p)?)?;
        assert!(img.width() as usize >= MIN_MAP_WIDTH.min(w) + 50, "{w}x{h}");
    }
    Ok(())
}

#[test]
fn bad_input_is_an_error_not_a_panic() {
    let values = ramp_map();
    let cases: Vec<(MapPreview, &str)> = vec![
        (
            MapPreview {
                width: W + 1,
                ..preview(&values, "")
            },
            "needs 1568 pixels but 1536 were given",
        ),
        (
            MapPreview {
                width: 0,
                values: &[],
                ..preview(&values, "")
            },
            "no pixels",
        ),
        (
            MapPreview {
                range: Some((2.0, 1.0)),
                ..preview(&values, "")
            },
            "colour range 2..1 is invalid",
        ),
        (
            MapPreview {
                range: Some((f64::NAN, 1.0)),
                ..preview(&values, "")
            },
            "invalid",
        ),
        (
            MapPreview {
                width: usize::MAX,
                height: 2,
                ..preview(&values, "")
            },
            "exceeds the limit",
        ),
    ];
    for (p, expected) in cases {
        let err = render_map_png(&p).err().map(|e| e.to_string());
        let msg = err.unwrap_or_default();
        assert!(msg.contains(expected), "{msg:?} lacks {expected:?}");
        assert!(!msg.contains('\n'));
    }
    let rgb = [[1u8, 2, 3]; 6];
    assert!(matches!(
        render_rgb_png(3, 2, &rgb, 0),
        Err(PreviewError::ZeroScale)
    ));
    assert!(matches!(
        render_rgb_png(3, 3, &rgb, 1),
        Err(PreviewError::SizeMismatch { .. })
    ));
    assert!(matches!(
        render_rgb_png(3, 2, &rgb, 1 << 20),
        Err(PreviewError::TooLarge { .. })
    ));
}

#[test]
fn rgb_images_are_upscaled_exactly() -> TestResult {
    let rgb: Vec<[u8; 3]> = (0..6u8).map(|i| [i * 40, 255 - i * 40, 7]).collect();
    let img = decode(&render_rgb_png(3, 2, &rgb, 10)?)?;
    assert_eq!(img.dimensions(), (30, 20));
    for y in 0..20 {
        for x in 0..30 {
            assert_eq!(px(&img, x, y), rgb[(y / 10) * 3 + x / 10], "({x}, {y})");
        }
    }
    Ok(())
}

#[test]
fn writers_are_atomic_and_name_the_path_on_failure() -> TestResult {
    let dir = tempfile::tempdir()?;
    let values = ramp_map();
    let map_path = dir.path().join("thickness.png");
    write_map_png(&map_path, &preview(&values, "Thickness"))?;
    let bytes = std::fs::read(&map_path)?;
    assert_eq!(bytes, render_map_png(&preview(&values, "Thickness"))?);

    let rgb_path = dir.path().join("colour.png");
    write_rgb_png(&rgb_path, 1, 1, &[[9, 8, 7]], 4)?;
    assert_eq!(decode(&std::fs::read(&rgb_path)?)?.dimensions(), (4, 4));

    // No temporary files left behind.
    let names: Vec<_> = std::fs::read_dir(dir.path())?
        .map(|e| e.map(|e| e.file_name()))
        .collect::<Result<_, _>>()?;
    assert_eq!(names.len(), 2, "{names:?}");

    let missing: PathBuf = dir.path().join("no-such-dir").join("map.png");
    let err = write_map_png(&missing, &preview(&values, "x"))
        .err()
        .ok_or("writing into a missing directory succeeded")?;
    let msg = err.to_string();
    assert!(msg.starts_with(&missing.display().to_string()), "{msg}");
    assert!(
        msg.contains("cannot write PNG") && !msg.contains('\n'),
        "{msg}"
    );
    Ok(())
}
