//! The browser viewer served at `GET /` (service-api.md, "GET /"): one self-contained HTML
//! page with inline CSS and JavaScript, embedded in the binary so the service works
//! offline and needs no static-file directory or CDN.

/// The whole viewer page. It talks only to the service's own `/v1` API and WebSocket.
pub const INDEX_HTML: &str = include_str!("viewer/index.html");

#[cfg(test)]
mod tests {
    use super::INDEX_HTML;

    /// The browser test (tests/browser/) and users' bookmarks rely on these ids; a
    /// rename must be deliberate.
    #[test]
    fn page_is_self_contained_and_keeps_its_test_ids() {
        assert!(INDEX_HTML.starts_with("<!doctype html>"));
        for id in [
            "example-select",
            "scene-text",
            "scene-file",
            "submit",
            "frame-img",
            "iteration",
            "pixel-fraction",
            "elapsed",
            "eta",
            "layer-image",
            "layer-samples",
            "layer-distance",
            "layer-classes",
            "stats",
            "error",
            "jobs",
            "cancel",
            "token",
        ] {
            assert!(
                INDEX_HTML.contains(&format!("id=\"{id}\"")),
                "missing id {id}"
            );
        }
        // Offline: no external scripts, styles or fonts.
        for bad in ["src=\"http", "href=\"http", "@import", "cdn."] {
            assert!(!INDEX_HTML.contains(bad), "external reference {bad}");
        }
    }

    /// The array literal after `const NAME = ` in the page's script, as JSON.
    fn js_const(name: &str) -> serde_json::Value {
        let start = INDEX_HTML
            .find(&format!("const {name} = "))
            .unwrap_or_else(|| panic!("no const {name} in the page"))
            + name.len()
            + 9;
        let end = start + INDEX_HTML[start..].find(';').expect("statement end");
        serde_json::from_str(&INDEX_HTML[start..end]).unwrap_or_else(|e| panic!("{name}: {e}"))
    }

    /// The distance legend is drawn in the browser from a copy of the JND colour scale;
    /// this keeps the copy equal to src/raster/colormap.rs (stops at t = k/8, ticks, top).
    #[test]
    fn distance_legend_matches_the_colormap() {
        use crate::raster::colormap::{ramp, TICKS, TOP_JND};
        let stops = js_const("DISTANCE_RAMP");
        let stops = stops.as_array().expect("array");
        assert_eq!(stops.len(), 9);
        for (k, c) in stops.iter().enumerate() {
            let want = ramp(k as f32 / 8.0);
            let got: Vec<u64> = c
                .as_array()
                .expect("rgb")
                .iter()
                .filter_map(serde_json::Value::as_u64)
                .collect();
            assert_eq!(got, want.map(u64::from).to_vec(), "stop {k}");
        }
        let ticks: Vec<f64> = js_const("DISTANCE_TICKS")
            .as_array()
            .expect("ticks")
            .iter()
            .filter_map(serde_json::Value::as_f64)
            .collect();
        assert_eq!(ticks, TICKS.map(f64::from).to_vec());
        assert_eq!(js_const("DISTANCE_TOP").as_f64(), Some(f64::from(TOP_JND)));
    }
}
