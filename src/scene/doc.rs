//! The scene document exactly as `shared/spec/scene-format.md` defines it (serde,
//! unknown fields refused). Owned by issue #2's scene work.
