//! The font of figures and videos: DejaVu Sans, embedded in the binary (the `dejavu` crate),
//! so drawing text needs no system fonts or fontconfig (the agent image has neither).

use std::sync::Once;

use plotters::style::FontStyle;

/// The family name under which the embedded font is registered with plotters.
pub const FAMILY: &str = "sans-serif";

/// Registers the embedded font with plotters (once; cheap afterwards). Call before drawing
/// any text.
pub fn ensure_registered() {
    static ONCE: Once = Once::new();
    ONCE.call_once(|| {
        plotters::style::register_font(FAMILY, FontStyle::Normal, dejavu::sans::regular())
            .unwrap_or_else(|_| panic!("the embedded DejaVu Sans font is valid"));
        plotters::style::register_font(FAMILY, FontStyle::Bold, dejavu::sans::bold())
            .unwrap_or_else(|_| panic!("the embedded DejaVu Sans Bold font is valid"));
    });
}
