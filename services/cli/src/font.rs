//! The font of every figure terl draws (report charts, render's burned-in text, frame grids).

use std::path::Path;

use anyhow::Result;
use plotters::style::FontStyle;

const FONT_PATHS: [&str; 3] = [
    "/usr/share/fonts/truetype/dejavu/DejaVuSans.ttf",
    "/usr/share/fonts/dejavu/DejaVuSans.ttf",
    "/usr/share/fonts/TTF/DejaVuSans.ttf",
];

/// Registers DejaVu Sans (package fonts-dejavu-core, installed by `deploy/setup.sh`) as the
/// charts' `sans-serif` font; PNG text needs a font file, SVG text does not.
pub(crate) fn register_font() -> Result<()> {
    static DONE: std::sync::OnceLock<std::result::Result<(), String>> = std::sync::OnceLock::new();
    DONE.get_or_init(|| {
        let path = FONT_PATHS
            .iter()
            .find(|p| Path::new(p).exists())
            .ok_or_else(|| {
                format!(
                    "no DejaVuSans.ttf in {FONT_PATHS:?}: install the fonts-dejavu-core package \
                     (./deploy/setup.sh does)"
                )
            })?;
        let bytes = std::fs::read(path).map_err(|e| format!("reading {path}: {e}"))?;
        let bytes: &'static [u8] = Box::leak(bytes.into_boxed_slice());
        plotters::style::register_font("sans-serif", FontStyle::Normal, bytes)
            .map_err(|_| format!("{path} is not a usable font"))
    })
    .clone()
    .map_err(|e| anyhow::anyhow!(e))
}
