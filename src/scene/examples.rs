//! The bundled example scenes (`scenes/*.json`), embedded in the binary by `build.rs` so
//! the service (`GET /v1/examples`) and `glimpse bench` need no file at run time.

/// (name, document), sorted by name.
pub const EXAMPLES: &[(&str, &str)] = include!(concat!(env!("OUT_DIR"), "/examples.rs"));
