//! `glimpse convert FILE --output SCENE.json`: the scene document an import produces
//! (meshes inline), so a person can read and edit what Glimpse understood
//! (scene-import.md).

use crate::scene::{validate_doc, Limits, SceneOrigin};
use anyhow::Context;
use std::path::PathBuf;

#[derive(clap::Args, Debug)]
pub struct ConvertArgs {
    /// The file to import: .pbrt (pbrt-v4), .gltf or .glb (glTF 2.0), .obj (with its MTL).
    pub scene: PathBuf,
    /// Where to write the scene document (JSON, meshes inline).
    #[arg(long, value_name = "SCENE.json")]
    pub output: PathBuf,
}

pub fn run(a: &ConvertArgs) -> anyhow::Result<()> {
    let limits = Limits::command_line();
    let shown = a.scene.display();
    let imported = crate::import::import_path(&a.scene, &limits)
        .map_err(|e| anyhow::anyhow!("{shown}: {e}"))?
        .ok_or_else(|| anyhow::anyhow!("{shown} is already a scene document"))?;
    for w in &imported.warnings {
        eprintln!("warning: {w}");
    }
    // The document written must be one Glimpse accepts: validate it first.
    let scene = validate_doc(&imported.doc, &SceneOrigin::Request, &limits)
        .map_err(|e| anyhow::anyhow!("{shown}: the imported scene is not valid: {e}"))?;
    for w in &scene.warnings {
        eprintln!("warning: {w}");
    }
    let json = serde_json::to_vec_pretty(&imported.doc)?;
    std::fs::write(&a.output, json)
        .with_context(|| format!("cannot write {}", a.output.display()))?;
    eprintln!(
        "{}: {} objects, {} triangles, {} materials",
        a.output.display(),
        scene.shapes.len(),
        scene.triangle_count(),
        scene.materials.len()
    );
    Ok(())
}
