//! placeholder
/// placeholder
pub struct Made {
    /// n
    pub images: usize,
    /// n
    pub bytes: usize,
    /// n
    pub notes: Vec<String>,
}
/// placeholder
pub fn write_report(
    _run: &std::path::Path,
    _out: &std::path::Path,
    _c: Option<&std::path::Path>,
) -> Result<Made, crate::appearance::AppearanceError> {
    todo!()
}
