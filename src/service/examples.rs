//! `GET /v1/examples`: the bundled scenes of `scenes/`, embedded in the binary so the
//! service needs no files at run time (service-api.md).

use super::error::ApiError;
use super::state::AppState;
use axum::extract::State;
use axum::response::IntoResponse;
use serde_json::{json, Value};

pub use crate::scene::examples::EXAMPLES;

pub async fn list(State(_st): State<AppState>) -> Result<impl IntoResponse, ApiError> {
    let examples: Vec<Value> = EXAMPLES
        .iter()
        .filter_map(|(name, text)| {
            // A bundled file that does not parse would be a build mistake: skip it rather
            // than fail the whole list (a unit test keeps them all valid JSON).
            serde_json::from_str::<Value>(text)
                .ok()
                .map(|scene| json!({ "name": name, "scene": scene, "text": text }))
        })
        .collect();
    Ok(axum::Json(json!({ "examples": examples })))
}

#[cfg(test)]
mod tests {
    #[test]
    fn bundled_examples_are_json_with_unique_names() {
        let mut names = std::collections::HashSet::new();
        for (name, text) in super::EXAMPLES {
            assert!(names.insert(*name), "duplicate example {name}");
            serde_json::from_str::<serde_json::Value>(text)
                .unwrap_or_else(|e| panic!("{name}: {e}"));
        }
    }

    /// The viewer submits these as they are: each must pass the server's own validation.
    #[test]
    fn bundled_examples_are_valid_requests_within_server_limits() {
        use crate::scene::{parse_scene, SceneOrigin};
        assert!(
            super::EXAMPLES.iter().any(|(n, _)| *n == "cornell-box"),
            "scenes/cornell-box.json is bundled"
        );
        for (name, text) in super::EXAMPLES {
            if let Err(e) = parse_scene(
                text,
                &SceneOrigin::Request,
                &crate::service::server_limits(),
            ) {
                panic!("example {name} is refused: {e}");
            }
        }
    }
}
