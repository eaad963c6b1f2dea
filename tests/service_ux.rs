//! What a person gets back from the service: a job's scene exactly as it was
//! written, and warnings for scenes that are valid but almost surely wrong, in the 201
//! answer and on the command line's stderr. The real binary on a loopback port.

mod common;

use common::LIT_SCENE;
use std::process::Command;
use std::time::Duration;

/// The lit scene with its lamp turned to face the sky: nothing in front of it.
fn lamp_facing_away() -> String {
    let s = LIT_SCENE.replace(
        r#""edge_u": [1, 0, 0], "edge_v": [0, 0, 1],
      "material": "lamp""#,
        r#""edge_u": [1, 0, 0], "edge_v": [0, 0, -1],
      "material": "lamp""#,
    );
    assert_ne!(s, LIT_SCENE, "the lamp was turned");
    s
}

/// Submits `body`, asserts a `201` with exactly one warning, and returns it.
async fn the_one_warning(c: &reqwest::Client, base: &str, body: String) -> String {
    let r = c
        .post(format!("{base}/v1/jobs"))
        .header("content-type", "application/json")
        .body(body)
        .send()
        .await
        .unwrap();
    assert_eq!(r.status(), 201);
    let created: serde_json::Value = r.json().await.unwrap();
    let warnings = created["warnings"].as_array().expect("warnings");
    assert_eq!(warnings.len(), 1, "{created}");
    warnings[0].as_str().unwrap().to_owned()
}

#[tokio::test]
async fn a_jobs_scene_comes_back_as_written_and_warnings_come_with_the_201() {
    let dir = tempfile::tempdir().unwrap();
    let port = common::free_port();
    let c = reqwest::Client::new();
    let server = common::spawn(dir.path(), port, None, &[], &[], &c).await;
    let base = format!("http://127.0.0.1:{port}");

    // Keys out of alphabetical order, `version` first, odd spacing, numbers as written.
    let written = LIT_SCENE.replace(r#""version": 1,"#, "\"version\":1 ,   ");
    let r = c
        .post(format!("{base}/v1/jobs"))
        .header("content-type", "application/json")
        .body(written.clone())
        .send()
        .await
        .unwrap();
    assert_eq!(r.status(), 201);
    let created: serde_json::Value = r.json().await.unwrap();
    assert!(
        created.get("warnings").is_none(),
        "a good scene warns of nothing: {created}"
    );
    let id = created["id"].as_str().unwrap().to_owned();
    let back = c
        .get(format!("{base}/v1/jobs/{id}/scene"))
        .send()
        .await
        .unwrap();
    assert_eq!(back.status(), 200);
    assert_eq!(
        back.headers()["content-type"].to_str().unwrap(),
        "application/json"
    );
    assert_eq!(back.text().await.unwrap(), written, "byte for byte");
    // Still so after the job ended and the server restarted.
    common::wait_state(&c, &base, &id, "succeeded", Duration::from_secs(60)).await;
    server.terminate().await;
    let _server = common::spawn(dir.path(), port, None, &[], &[], &c).await;
    let again = c
        .get(format!("{base}/v1/jobs/{id}/scene"))
        .send()
        .await
        .unwrap()
        .text()
        .await
        .unwrap();
    assert_eq!(again, written);
    let missing = c
        .get(format!(
            "{base}/v1/jobs/00000000-0000-7000-8000-000000000000/scene"
        ))
        .send()
        .await
        .unwrap();
    assert_eq!(missing.status(), 404);
    let e: serde_json::Value = missing.json().await.unwrap();
    assert_eq!(e["error"]["code"], "not_found");

    // A lamp facing away from everything: accepted, with the warning naming it.
    let w = the_one_warning(&c, &base, lamp_facing_away()).await;
    assert!(w.contains("objects[2]") && w.contains("faces away"), "{w}");
}

/// `glimpse render SCENE` in `dir` (to `out.png`, with `args`), which must succeed: its
/// stderr, where the warnings go.
fn render_stderr(dir: &std::path::Path, scene: &str, args: &[&str]) -> String {
    let o = Command::new(env!("CARGO_BIN_EXE_glimpse"))
        .current_dir(dir)
        .args(["render", scene, "--output", "out.png"])
        .args(args)
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr).into_owned();
    assert!(o.status.success(), "{err}");
    err
}

#[test]
fn the_command_line_prints_scene_warnings_on_stderr() {
    let dir = tempfile::tempdir().unwrap();
    std::fs::write(dir.path().join("away.json"), lamp_facing_away()).unwrap();
    let err = render_stderr(dir.path(), "away.json", &["--mode", "reference"]);
    assert!(
        err.lines()
            .any(|l| l.starts_with("warning: objects[2]") && l.contains("faces away")),
        "{err}"
    );
}

#[tokio::test]
async fn retention_forgets_the_oldest_finished_jobs_and_their_files() {
    let dir = tempfile::tempdir().unwrap();
    let port = common::free_port();
    let c = reqwest::Client::new();
    let server = common::spawn(dir.path(), port, None, &[], &[], &c).await;
    let base = format!("http://127.0.0.1:{port}");
    let mut ids = Vec::new();
    for _ in 0..3 {
        let r = c
            .post(format!("{base}/v1/jobs"))
            .header("content-type", "application/json")
            .body(LIT_SCENE)
            .send()
            .await
            .unwrap();
        assert_eq!(r.status(), 201);
        let id = r.json::<serde_json::Value>().await.unwrap()["id"]
            .as_str()
            .unwrap()
            .to_owned();
        common::wait_state(&c, &base, &id, "succeeded", Duration::from_secs(60)).await;
        ids.push(id);
    }
    for id in &ids {
        assert!(dir.path().join("jobs").join(id).join("image.png").exists());
    }
    server.terminate().await;
    // Keep one: the two oldest go, with their folders; the newest stays.
    let _server = common::spawn(dir.path(), port, None, &["--keep-jobs", "1"], &[], &c).await;
    // A job reads 404 from the moment its deletion starts, before its folder is gone:
    // wait for both, for each of the two oldest.
    let deadline = std::time::Instant::now() + Duration::from_secs(10);
    for id in &ids[..2] {
        loop {
            let st = c
                .get(format!("{base}/v1/jobs/{id}"))
                .send()
                .await
                .unwrap()
                .status();
            if st == 404 && !dir.path().join("jobs").join(id).exists() {
                break;
            }
            assert!(
                std::time::Instant::now() < deadline,
                "{id} not forgotten: {st}, folder there: {}",
                dir.path().join("jobs").join(id).exists()
            );
            tokio::time::sleep(Duration::from_millis(50)).await;
        }
    }
    let newest = common::job(&c, &base, &ids[2]).await;
    assert_eq!(newest["state"], "succeeded");
    assert!(dir
        .path()
        .join("jobs")
        .join(&ids[2])
        .join("image.png")
        .exists());
}

/// The distinct colours of a PNG.
fn colours(png: &[u8]) -> std::collections::BTreeSet<[u32; 3]> {
    let img = glimpse::raster::decode_image(png).expect("a PNG");
    img.pixels()
        .iter()
        .map(|p| [p.x, p.y, p.z].map(f32::to_bits))
        .collect()
}

#[tokio::test]
async fn earlier_iterations_are_kept_with_layers_that_still_show_the_method() {
    let dir = tempfile::tempdir().unwrap();
    let port = common::free_port();
    let c = reqwest::Client::new();
    let _server = common::spawn(dir.path(), port, None, &[], &[], &c).await;
    let base = format!("http://127.0.0.1:{port}");
    let scene: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string("scenes/cornell-box.json").unwrap()).unwrap();
    let id = common::submit(&c, &base, &scene).await;
    common::wait_state(&c, &base, &id, "succeeded", Duration::from_secs(120)).await;
    let last = common::job(&c, &base, &id).await["progress"]["iteration"]
        .as_u64()
        .unwrap();
    assert!(last >= 2, "too few iterations to test: {last}");
    // The worker writes the last kept iterations just after `done`: wait for them.
    let deadline = std::time::Instant::now() + Duration::from_secs(10);
    let listed = loop {
        let l = common::get_json(&c, &format!("{base}/v1/jobs/{id}/iterations")).await;
        let its = l["iterations"].as_array().unwrap().clone();
        if its.len() as u64 == last + 1 || std::time::Instant::now() > deadline {
            break its;
        }
        tokio::time::sleep(Duration::from_millis(50)).await;
    };
    let numbers: Vec<u64> = listed
        .iter()
        .map(|i| i["iteration"].as_u64().unwrap())
        .collect();
    // A frame is skipped only if the frames waiting for the writer already hold 4 Mpixels
    // (never at 256²); the first and the final are there in any case.
    assert!(numbers.len() >= 3, "{listed:?}");
    assert_eq!((numbers[0], *numbers.last().unwrap()), (0, last));
    let frame = |n: u64, layer: &str| {
        let url = format!("{base}/v1/jobs/{id}/frame?iteration={n}&layer={layer}");
        let c = c.clone();
        async move { c.get(url).send().await.unwrap() }
    };
    for it in &listed {
        let n = it["iteration"].as_u64().unwrap();
        for layer in it["layers"].as_array().unwrap() {
            let r = frame(n, layer.as_str().unwrap()).await;
            assert_eq!(r.status(), 200, "iteration {n} {layer}");
            assert!(r.bytes().await.unwrap().starts_with(b"\x89PNG"));
        }
    }
    // At the end every triangle is final: one colour. An earlier iteration still shows
    // where refinement went.
    let final_classes = frame(last, "classes").await.bytes().await.unwrap();
    let n1 = numbers[1];
    let early_classes = frame(n1, "classes").await.bytes().await.unwrap();
    assert!(colours(&final_classes).len() <= 2, "final classes");
    assert!(
        colours(&early_classes).len() >= 3,
        "iteration {n1}'s classes"
    );
    let early_distance = frame(n1, "distance").await.bytes().await.unwrap();
    assert!(
        colours(&early_distance).len() > 3,
        "iteration {n1}'s distance"
    );
    // The final iteration's image is the latest frame's.
    assert_eq!(
        frame(last, "image").await.bytes().await.unwrap(),
        c.get(format!("{base}/v1/jobs/{id}/frame"))
            .send()
            .await
            .unwrap()
            .bytes()
            .await
            .unwrap()
    );

    // Mistakes answer with what was wrong and where.
    let r = frame(last + 100, "image").await;
    assert_eq!(r.status(), 404);
    let e: serde_json::Value = r.json().await.unwrap();
    let msg = e["error"]["message"].as_str().unwrap();
    assert!(
        msg.contains("not kept") && msg.contains("from 0 to"),
        "{msg}"
    );
    assert_eq!(e["error"]["path"], "iteration");
    let r = c
        .get(format!("{base}/v1/jobs/{id}/frame?iteration=-1"))
        .send()
        .await
        .unwrap();
    assert_eq!(r.status(), 400);
    let e: serde_json::Value = r.json().await.unwrap();
    assert_eq!(e["error"]["path"], "iteration");
    let r = c
        .get(format!("{base}/v1/jobs/{id}/frame?iteration=0&format=exr"))
        .send()
        .await
        .unwrap();
    assert_eq!(r.status(), 400);
    assert_eq!(frame(0, "objects").await.status(), 404);

    // They are the job's files: deleting the job removes them.
    let folder = dir.path().join("jobs").join(&id).join("iterations");
    assert!(folder.is_dir());
    common::delete(&c, &base, &id).await;
    assert!(!folder.exists());
    let r = c
        .get(format!("{base}/v1/jobs/{id}/iterations"))
        .send()
        .await
        .unwrap();
    assert_eq!(r.status(), 404);
}

/// A room (floor, ceiling, side and front walls) whose only lamp stands just inside the
/// missing back wall and faces out through it: the ceiling and the floor lie beside it
/// at grazing angles, so some object lies in its hemisphere, yet almost none of its light
/// reaches anything and the picture is nearly black.
fn lamp_facing_out_of_an_open_room() -> String {
    let quad = |corner: &str, u: &str, v: &str, m: &str| {
        format!(
            r#"{{ "type": "quad", "material": "{m}", "corner": {corner}, "edge_u": {u}, "edge_v": {v} }}"#
        )
    };
    let objects = [
        quad("[-2, 0, -2]", "[0, 0, 4]", "[4, 0, 0]", "white"),
        quad("[-2, 2, -2]", "[4, 0, 0]", "[0, 0, 4]", "white"),
        quad("[-2, 0, -2]", "[0, 2, 0]", "[0, 0, 4]", "white"),
        quad("[2, 0, -2]", "[0, 0, 4]", "[0, 2, 0]", "white"),
        quad("[-2, 0, 2]", "[4, 0, 0]", "[0, 2, 0]", "white"),
        // edge_u × edge_v = x × −y = −z: out of the room, through the missing wall.
        quad("[-0.5, 1.5, -1.9]", "[1, 0, 0]", "[0, -1, 0]", "lamp"),
    ]
    .join(",\n    ");
    format!(
        r#"{{
  "version": 1, "name": "open room",
  "image": {{ "width": 48, "height": 36 }},
  "camera": {{ "position": [0, 1, 1.9], "look_at": [0, 1, 0], "fov_y": 60 }},
  "materials": {{ "white": {{ "type": "diffuse", "albedo": [0.7, 0.7, 0.7] }},
                 "lamp": {{ "type": "emissive", "radiance": [10, 10, 10] }} }},
  "objects": [
    {objects}
  ],
  "render": {{ "mode": "reference", "samples_per_pixel": 2 }}
}}"#
    )
}

#[tokio::test]
async fn a_lamp_facing_out_of_an_open_room_is_named_in_the_201() {
    let dir = tempfile::tempdir().unwrap();
    let port = common::free_port();
    let c = reqwest::Client::new();
    let _server = common::spawn(dir.path(), port, None, &[], &[], &c).await;
    let base = format!("http://127.0.0.1:{port}");
    let w = the_one_warning(&c, &base, lamp_facing_out_of_an_open_room()).await;
    assert!(
        w.starts_with("objects[5]: only") && w.contains("which way it faces"),
        "{w}"
    );
}

#[test]
fn the_command_line_names_a_lamp_facing_out_of_an_open_room() {
    let dir = tempfile::tempdir().unwrap();
    std::fs::write(
        dir.path().join("open.json"),
        lamp_facing_out_of_an_open_room(),
    )
    .unwrap();
    let err = render_stderr(dir.path(), "open.json", &[]);
    assert!(
        err.lines()
            .any(|l| l.starts_with("warning: objects[5]: only") && l.contains("which way it faces")),
        "{err}"
    );
}

#[tokio::test]
async fn the_serve_limit_flags_refuse_with_422_or_cap_bounces_with_a_warning() {
    let dir = tempfile::tempdir().unwrap();
    let port = common::free_port();
    let c = reqwest::Client::new();
    let flags = ["--max-width", "32", "--max-bounces", "8"];
    let _server = common::spawn(dir.path(), port, None, &flags, &[], &c).await;
    let post = |body: String| {
        c.post(format!("http://127.0.0.1:{port}/v1/jobs"))
            .header("content-type", "application/json")
            .body(body)
            .send()
    };
    // 40 pixels wide over a limit of 32: a parameter, not a body too large.
    let r = post(LIT_SCENE.to_owned()).await.unwrap();
    assert_eq!(r.status(), 422);
    let e: serde_json::Value = r.json().await.unwrap();
    assert_eq!(e["error"]["code"], "over_limit", "{e}");
    assert_eq!(e["error"]["path"], "image.width", "{e}");
    let m = e["error"]["message"].as_str().unwrap();
    assert!(
        m.contains("limit of 32") && m.contains("glimpse serve --max-width"),
        "{m}"
    );
    // pbrt's `maxdepth 65` over a cap of 8: accepted, capped, and said.
    let deep = LIT_SCENE
        .replace(
            r#""width": 40, "height": 30"#,
            r#""width": 32, "height": 24"#,
        )
        .replace(r#""max_bounces": 2"#, r#""max_bounces": 65"#);
    let r = post(deep).await.unwrap();
    assert_eq!(r.status(), 201);
    let created: serde_json::Value = r.json().await.unwrap();
    let w = created["warnings"].as_array().expect("warnings");
    assert_eq!(w.len(), 1, "{created}");
    let w = w[0].as_str().unwrap();
    assert!(
        w.starts_with("render.max_bounces: 65 is above this server's cap of 8")
            && w.contains("glimpse serve --max-bounces"),
        "{w}"
    );
}
