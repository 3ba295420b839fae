//! The lens's field of view: which incidence angle each image column sees.
//!
//! Geometry (the rig of `method.md`): the stage turns the sample about the vertical axis,
//! which is parallel to the image columns, so the plane of incidence is horizontal and the
//! stage angle `theta_stage` is the incidence angle of the camera's optical axis. A pinhole
//! lens of horizontal field of view `f` across an image `width` pixels wide has a focal
//! length of `focal_px = (width / 2) / tan(f / 2)` pixels; the ray through horizontal
//! image position `x` (pixels from the image's left edge; column `c` has its centre at
//! `x = c + 0.5`, the optical axis is at `cx = width / 2`) leaves the axis by
//! `atan((x - cx) / focal_px)` in the plane of incidence.
//!
//! Sign convention: seen from the camera, the stage turns the sample's normal towards the
//! image's right (in camera coordinates, `+z` along the optical axis and `+x` to the right,
//! the normal is `(sin theta_stage, 0, -cos theta_stage)`), so the incidence angle grows
//! from left to right:
//!
//! ```text
//! theta(x) = theta_stage + atan((x - cx) / focal_px)
//! ```
//!
//! The image centre sees exactly `theta_stage`, the left and right edges
//! `theta_stage -+ f / 2`. A rig whose sample turns the other way flips its images left to
//! right. Not modelled: the vertical field (a row off the image's horizon meets the sample
//! slightly out of the plane of incidence, a second-order change of the angle) and where
//! the lamp sits (each pixel is assumed lit from its own specular direction).

/// A pinhole lens's horizontal field of view, checked to lie in `(0, 180)` degrees.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FieldOfView {
    horizontal_deg: f64,
}

impl FieldOfView {
    /// A horizontal field of view of `horizontal_deg` degrees; `None` unless it is finite
    /// and inside `(0, 180)`.
    pub fn new(horizontal_deg: f64) -> Option<Self> {
        (horizontal_deg.is_finite() && horizontal_deg > 0.0 && horizontal_deg < 180.0)
            .then_some(Self { horizontal_deg })
    }

    /// The full horizontal field of view, degrees.
    pub fn horizontal_deg(&self) -> f64 {
        self.horizontal_deg
    }

    /// The focal length in pixels of an image `width` pixels wide.
    pub fn focal_px(&self, width: usize) -> f64 {
        0.5 * width as f64 / libm::tan(0.5 * self.horizontal_deg.to_radians())
    }

    /// How much more steeply than the optical axis the ray through horizontal position
    /// `x_px` (pixels from the left edge of an image `width` pixels wide) meets the sample,
    /// degrees: 0 at the centre, `-f/2` at `x_px = 0`, `+f/2` at `x_px = width`.
    pub fn offset_deg(&self, x_px: f64, width: usize) -> f64 {
        libm::atan((x_px - 0.5 * width as f64) / self.focal_px(width)).to_degrees()
    }

    /// [`FieldOfView::offset_deg`] at the centre of column `col`.
    pub fn column_offset_deg(&self, col: usize, width: usize) -> f64 {
        self.offset_deg(col as f64 + 0.5, width)
    }

    /// The incidence angle column `col` sees when the stage is at `stage_deg`.
    pub fn incidence_deg(&self, stage_deg: f64, col: usize, width: usize) -> f64 {
        stage_deg + self.column_offset_deg(col, width)
    }
}
