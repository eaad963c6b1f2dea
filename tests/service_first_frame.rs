//! The first picture where the person is: the real server binary on a loopback port, a
//! real HTTP client and a WebSocket client, timing from sending the `POST` to the first
//! binary frame received on the job's stream (opened right after the `201`, as the
//! viewer does). A file of its own, so no other test's renders share the cores while it
//! times.
//!
//! Run: `cargo test --test service_first_frame -- --nocapture` (prints the medians).

mod common;

use futures_util::StreamExt;
use serde_json::Value;
use std::time::Instant;
use tokio_tungstenite::tungstenite::Message;

/// Runs per size; the median is judged.
const RUNS: usize = 5;

/// The Cornell box (`scenes/cornell-box.json`) at `w × h`.
fn cornell_box(w: u32, h: u32) -> Value {
    let path = concat!(env!("CARGO_MANIFEST_DIR"), "/scenes/cornell-box.json");
    let mut doc: Value = serde_json::from_str(&std::fs::read_to_string(path).unwrap()).unwrap();
    doc["image"]["width"] = w.into();
    doc["image"]["height"] = h.into();
    doc
}

/// What a client saw of a job's first frame: the time from sending the POST to its
/// binary message, the `frame` message before it, and its PNG.
struct FirstFrame {
    ms: f64,
    header: Value,
    png: Vec<u8>,
}

/// Submits `scene`, times its first frame on the stream, then cancels the job and
/// deletes it once it has ended (`DELETE` waits for the files written after the end), so
/// the next run finds the server idle.
async fn first_frame(c: &reqwest::Client, base: &str, scene: &Value) -> FirstFrame {
    let t0 = Instant::now();
    let id = common::submit(c, base, scene).await;
    let url = format!("{}/v1/jobs/{id}/stream", base.replacen("http", "ws", 1));
    let (mut ws, _) = tokio_tungstenite::connect_async(url).await.unwrap();
    let mut header = Value::Null;
    let (ms, png) = loop {
        match ws.next().await.expect("a frame before the stream ends") {
            Ok(Message::Text(t)) => header = serde_json::from_str(&t).unwrap(),
            Ok(Message::Binary(b)) => break (t0.elapsed().as_secs_f64() * 1e3, b.to_vec()),
            Ok(_) => {}
            Err(e) => panic!("stream: {e}"),
        }
    };
    let _ = c.post(format!("{base}/v1/jobs/{id}/cancel")).send().await;
    while let Some(Ok(m)) = ws.next().await {
        if matches!(m, Message::Close(_)) {
            break;
        }
    }
    common::delete(c, base, &id).await;
    FirstFrame { ms, header, png }
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

/// A large image's first frame is its preview, sent at most 512 px a side with its own
/// size and the image's in the frame message (the client scales it up): it reaches the
/// client within 300 ms of the POST at 2048², 100 ms at 1024×768. Asserted within twice
/// these targets, for a loaded machine; the medians are printed.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_first_frame_reaches_the_client_within_its_target() {
    let dir = tempfile::tempdir().unwrap();
    let port = common::free_port();
    let c = reqwest::Client::new();
    let _server = common::spawn(dir.path(), port, None, &["--workers", "1"], &[], &c).await;
    let base = format!("http://127.0.0.1:{port}");
    // Warm-up: the page cache, the worker's thread pool.
    first_frame(&c, &base, &cornell_box(320, 240)).await;
    let mut measured = Vec::new();
    for (w, h, target_ms) in [(2048u32, 2048u32, 300.0), (1024, 768, 100.0)] {
        let scene = cornell_box(w, h);
        let mut times = Vec::new();
        let mut first = None;
        for _ in 0..RUNS {
            let f = first_frame(&c, &base, &scene).await;
            times.push(f.ms);
            first.get_or_insert(f);
        }
        let m = median(times.clone());
        let first = first.unwrap();
        eprintln!(
            "{w}x{h}: POST -> first frame on the client, median {m:.0} ms (target {target_ms} ms) of {times:.0?}; a {} kB PNG",
            first.png.len() / 1000
        );
        measured.push((w, h, m, target_ms, first));
    }
    for (w, h, m, target_ms, f) in measured {
        let size = glimpse::raster::png_size(&f.png).expect("a PNG");
        let header = &f.header;
        assert_eq!(header["type"], "frame", "{header}");
        assert_eq!(header["preview"], true, "{header}");
        assert_eq!(header["width"], size.0, "{header}");
        assert_eq!(header["height"], size.1, "{header}");
        assert_eq!(header["image_width"], w, "{header}");
        assert_eq!(header["image_height"], h, "{header}");
        assert!(size.0.max(size.1) <= 512, "{w}x{h}: a {size:?} preview");
        // The aspect kept: the shorter side to within a pixel.
        let expect_h = f64::from(h) * f64::from(size.0) / f64::from(w);
        assert!((f64::from(size.1) - expect_h).abs() <= 1.0, "{size:?}");
        assert!(
            m <= 2.0 * target_ms,
            "{w}x{h}: the first frame took {m:.0} ms (target {target_ms} ms)"
        );
    }
}
