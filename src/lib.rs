//! Glimpse: a render service that traces only the pixels a person would notice.
//!
//! It follows Farrugia & Péroche, *A Progressive Rendering Algorithm Using an Adaptive
//! Perceptually Based Image Metric* (Eurographics 2004). Data flows one way:
//!
//! `scene` (document → validated [`scene::Scene`]) → `tracer` (the pixel oracle) →
//! `progressive` (Delaunay + Gouraud + classification, driven by `metric` over `vision`)
//! → frames → `service` (REST, WebSocket, store) and the command line.
//!
//! See `ARCHITECTURE.md` for the codemap and the invariants.

pub mod bench;
pub mod cancel;
pub mod cli;
pub mod denoise;
pub mod import;
pub mod metric;
pub mod progressive;
pub mod raster;
pub mod scene;
pub mod service;
pub mod tracer;
pub mod vision;
