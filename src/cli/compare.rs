//! `glimpse compare A B`: the perceptual distance between two images (issue #3).

use std::path::PathBuf;

#[derive(clap::Args, Debug)]
pub struct CompareArgs {
    pub a: PathBuf,
    pub b: PathBuf,
    #[arg(long)]
    pub stats: Option<PathBuf>,
    #[arg(long)]
    pub map: Option<PathBuf>,
    /// Evaluate every pixel instead of the adaptive quad-tree.
    #[arg(long)]
    pub full: bool,
    #[arg(long, default_value_t = 100.0)]
    pub display_peak: f32,
    #[arg(long, default_value_t = 28.0)]
    pub ppd: f32,
}

pub fn run(a: &CompareArgs) -> anyhow::Result<()> {
    let _ = a;
    anyhow::bail!("compare: not built yet (issue #3)")
}
