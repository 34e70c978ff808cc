//! The embedded font. plotters' `ab_glyph` backend draws text only with fonts registered at
//! run time; registering DejaVu Sans under the generic name `sans-serif` makes every picture
//! independent of the fonts installed on the machine.

use std::sync::OnceLock;

use plotters::style::FontStyle;

use crate::VizError;

/// The family name the pictures use.
pub(crate) const FAMILY: &str = "sans-serif";

/// Registers the font once per process.
pub(crate) fn ensure_registered() -> Result<(), VizError> {
    static REGISTERED: OnceLock<bool> = OnceLock::new();
    let ok = *REGISTERED.get_or_init(|| {
        plotters::style::register_font(FAMILY, FontStyle::Normal, dejavu::sans::regular()).is_ok()
            && plotters::style::register_font(FAMILY, FontStyle::Bold, dejavu::sans::bold()).is_ok()
    });
    if ok {
        Ok(())
    } else {
        Err(VizError::draw("text", "the embedded DejaVu Sans font could not be parsed"))
    }
}
