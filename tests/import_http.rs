//! Uploads over HTTP against the real server (scene-import.md "Over HTTP"): a `.glb` and a
//! zip of a pbrt scene with its PLY files become jobs that finish with a frame; a bundle
//! reaching outside itself, a link, a missing file, a zip bomb, a zip64 directory (how 10^6
//! entries would be written), a truncated `.glb` and a 2 GiB accessor count each get one
//! clear 4xx within a second, and the server stays up.

mod common;

use std::path::Path;
use std::time::{Duration, Instant};

/// A lit triangle as a `.glb`; `count` is its POSITION accessor's count (3 is honest).
fn glb(count: u64) -> Vec<u8> {
    let mut bin = Vec::new();
    for v in [[-1f32, -1.0, 0.0], [1.0, -1.0, 0.0], [0.0, 1.0, 0.0]] {
        for c in v {
            bin.extend(c.to_le_bytes());
        }
    }
    let json = format!(
        r#"{{"asset":{{"version":"2.0"}},"scene":0,"scenes":[{{"nodes":[0,1]}}],
        "nodes":[{{"mesh":0}},{{"camera":0,"translation":[0,0,4]}}],
        "cameras":[{{"type":"perspective","perspective":{{"yfov":0.8,"znear":0.1,"aspectRatio":1.0}}}}],
        "meshes":[{{"primitives":[{{"attributes":{{"POSITION":0}}}}]}}],
        "accessors":[{{"bufferView":0,"componentType":5126,"count":{count},"type":"VEC3","min":[-1,-1,0],"max":[1,1,0]}}],
        "bufferViews":[{{"buffer":0,"byteLength":36}}],"buffers":[{{"byteLength":36}}]}}"#
    );
    let mut j = json.into_bytes();
    while j.len() % 4 != 0 {
        j.push(b' ');
    }
    let mut out = b"glTF".to_vec();
    out.extend(2u32.to_le_bytes());
    out.extend(((12 + 8 + j.len() + 8 + bin.len()) as u32).to_le_bytes());
    out.extend((j.len() as u32).to_le_bytes());
    out.extend(0x4E4F_534Au32.to_le_bytes());
    out.extend(j);
    out.extend((bin.len() as u32).to_le_bytes());
    out.extend(0x004E_4942u32.to_le_bytes());
    out.extend(bin);
    out
}

/// Veach's bidir room with its PLY files, `scene` replacing the pbrt file's text.
fn bidir_bundle(edit: impl Fn(String) -> String, skip: Option<&str>) -> Vec<u8> {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes/imported/veach-bidir");
    let text = std::fs::read_to_string(dir.join("scene-v4.pbrt")).unwrap();
    let mut entries = vec![("scene.pbrt".to_string(), edit(text).into_bytes(), 0o100_644)];
    for e in std::fs::read_dir(dir.join("models")).unwrap() {
        let e = e.unwrap();
        let name = format!("models/{}", e.file_name().to_string_lossy());
        if Some(name.as_str()) != skip {
            entries.push((name, std::fs::read(e.path()).unwrap(), 0o100_644));
        }
    }
    let refs: Vec<(&str, Vec<u8>, u32)> = entries
        .iter()
        .map(|(n, d, m)| (n.as_str(), d.clone(), *m))
        .collect();
    common::zip(&refs, true)
}

/// 1 GiB of zeros deflated in 1 MiB slices (never held whole): about 1 MiB packed.
fn zip_bomb() -> Vec<u8> {
    use miniz_oxide::deflate::core::{
        compress, create_comp_flags_from_zip_params, CompressorOxide, TDEFLFlush,
    };
    let mut c = CompressorOxide::new(create_comp_flags_from_zip_params(6, -15, 0));
    let zeros = vec![0u8; 1 << 20];
    let mut packed = Vec::new();
    let mut buf = vec![0u8; 1 << 20];
    for i in 0..1024 {
        let flush = if i == 1023 {
            TDEFLFlush::Finish
        } else {
            TDEFLFlush::None
        };
        let mut input = &zeros[..];
        loop {
            let (_, used, wrote) = compress(&mut c, input, &mut buf, flush);
            packed.extend_from_slice(&buf[..wrote]);
            input = &input[used..];
            if input.is_empty() && (flush != TDEFLFlush::Finish || wrote < buf.len()) {
                break;
            }
        }
    }
    // A stored-entry zip, then the directory says deflate and 1 GiB.
    let mut z = common::zip(&[("scene.pbrt", packed.clone(), 0o100_644)], false);
    let d = z
        .windows(4)
        .rposition(|w| w == [0x50, 0x4b, 0x01, 0x02])
        .unwrap();
    z[d + 10] = 8;
    z[d + 24..d + 28].copy_from_slice(&(1u32 << 30).to_le_bytes());
    z
}

async fn post(
    c: &reqwest::Client,
    base: &str,
    ctype: &str,
    body: Vec<u8>,
) -> (u16, serde_json::Value, Duration) {
    let t = Instant::now();
    let r = c
        .post(format!(
            "{base}/v1/jobs?spp=4&width=48&height=48&mode=progressive"
        ))
        .header("content-type", ctype)
        .body(body)
        .send()
        .await
        .unwrap();
    let status = r.status().as_u16();
    let v = r.json().await.unwrap_or(serde_json::Value::Null);
    (status, v, t.elapsed())
}

async fn finishes_with_a_frame(c: &reqwest::Client, base: &str, id: &str) {
    let deadline = Instant::now() + Duration::from_secs(120);
    loop {
        let j = common::job(c, base, id).await;
        match j["state"].as_str().unwrap() {
            "succeeded" => break,
            "failed" | "cancelled" => panic!("{j}"),
            _ => {}
        }
        assert!(Instant::now() < deadline, "job did not finish");
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
    let r = c
        .get(format!("{base}/v1/jobs/{id}/frame"))
        .send()
        .await
        .unwrap();
    assert_eq!(r.status(), 200);
    assert!(r.bytes().await.unwrap().starts_with(b"\x89PNG"));
}

#[tokio::test]
async fn uploads_render_and_bad_bundles_get_one_clear_4xx() {
    let data = tempfile::tempdir().unwrap();
    let port = common::free_port();
    let c = reqwest::Client::new();
    let _srv = common::spawn(data.path(), port, None, &[], &[], &c).await;
    let base = format!("http://127.0.0.1:{port}");

    // A .glb: the camera is the file's, the missing light supplied with a warning.
    let (s, v, _) = post(&c, &base, "model/gltf-binary", glb(3)).await;
    assert_eq!(s, 201, "{v}");
    assert!(v["warnings"].to_string().contains("no light"), "{v}");
    finishes_with_a_frame(&c, &base, v["id"].as_str().unwrap()).await;

    // A zip of a pbrt scene with its PLY files.
    let (s, v, _) = post(&c, &base, "application/zip", bidir_bundle(|t| t, None)).await;
    assert_eq!(s, 201, "{v}");
    finishes_with_a_frame(&c, &base, v["id"].as_str().unwrap()).await;

    let escape = bidir_bundle(
        |t| t.replace("models/Mesh007.ply", "../models/Mesh007.ply"),
        None,
    );
    let missing = bidir_bundle(|t| t, Some("models/Mesh007.ply"));
    let absolute = bidir_bundle(|t| t.replace("models/Mesh007.ply", "/etc/passwd"), None);
    let link = common::zip(
        &[
            ("scene.pbrt", b"WorldBegin".to_vec(), 0o100_644),
            ("models/a.ply", b"/etc/passwd".to_vec(), 0o120_777),
        ],
        false,
    );
    let mut zip64 = common::eocd(Vec::new(), &[], 0);
    let n = zip64.len();
    zip64[n - 12..n - 10].copy_from_slice(&0xffffu16.to_le_bytes());
    let glb_bytes = glb(3);
    let truncated = glb_bytes[..glb_bytes.len() - 20].to_vec();
    let cases: Vec<(&str, &str, Vec<u8>, &str)> = vec![
        ("escape", "application/zip", escape, "leaves the bundle"),
        (
            "missing",
            "application/zip",
            missing,
            "\"models/Mesh007.ply\" is not in the bundle",
        ),
        ("absolute", "application/zip", absolute, "absolute"),
        ("link", "application/zip", link, "symbolic link"),
        (
            "bomb",
            "application/zip",
            zip_bomb(),
            "refused before unpacking",
        ),
        ("10^6 entries (zip64)", "application/zip", zip64, "zip64"),
        ("truncated glb", "model/gltf-binary", truncated, "truncated"),
        (
            "2 GiB accessor",
            "model/gltf-binary",
            glb(1 << 31),
            "do not fit",
        ),
        (
            "not a zip",
            "application/zip",
            b"hello".to_vec(),
            "not a zip",
        ),
    ];
    for (what, ctype, body, says) in cases {
        let (s, v, t) = post(&c, &base, ctype, body).await;
        assert!((400..500).contains(&s), "{what}: {s} {v}");
        let e = &v["error"];
        let msg = format!(
            "{} (at {})",
            e["message"].as_str().unwrap_or(""),
            e["path"].as_str().unwrap_or("")
        );
        assert!(msg.contains(says), "{what}: {msg}");
        assert!(t < Duration::from_secs(1), "{what}: {t:?}");
        eprintln!("{what}: {s} in {t:?}: {msg}");
    }
    // Still up.
    let r = c.get(format!("{base}/healthz")).send().await.unwrap();
    assert_eq!(r.status(), 200);
}

/// Every render setting an upload's query may carry is applied to the imported document
/// (none ignored without a word), and a bad value is a 400 naming the parameter.
#[tokio::test]
async fn an_uploads_query_sets_denoise_and_sampler_or_is_refused() {
    let data = tempfile::tempdir().unwrap();
    let port = common::free_port();
    let c = reqwest::Client::new();
    let _srv = common::spawn(data.path(), port, None, &[], &[], &c).await;
    let base = format!("http://127.0.0.1:{port}");
    let upload = |query: &str| {
        c.post(format!("{base}/v1/jobs?width=16&height=16&{query}"))
            .header("content-type", "model/gltf-binary")
            .body(glb(3))
            .send()
    };
    let r = upload("denoise=false&sampler=zsobol&mode=reference")
        .await
        .unwrap();
    assert_eq!(r.status(), 201);
    let id = r.json::<serde_json::Value>().await.unwrap()["id"]
        .as_str()
        .unwrap()
        .to_owned();
    let doc = common::get_json(&c, &format!("{base}/v1/jobs/{id}/scene")).await;
    assert_eq!(doc["render"]["denoise"], false, "{doc}");
    assert_eq!(doc["render"]["sampler"], "zsobol", "{doc}");
    for (query, path) in [("denoise=maybe", "denoise"), ("sampler=halton", "sampler")] {
        let r = upload(query).await.unwrap();
        assert_eq!(r.status(), 400, "{query}");
        let v: serde_json::Value = r.json().await.unwrap();
        assert_eq!(v["error"]["code"], "invalid_parameter", "{v}");
        assert_eq!(v["error"]["path"], path, "{v}");
    }
}
