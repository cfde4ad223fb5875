//! Fuzz target for the loader: a proptest mutator over GLB containers and glTF JSON, starting
//! from the samples (`samples/*.glb`) and the seed corpus (`crates/photongrid/fuzz-corpus/`),
//! asserting that `load` never panics (not even into the loader's last-resort net), never takes
//! more than a bounded time per file and keeps the process within a bounded memory.
//!
//! Mutations: numbers set to extremes (0, −1, 2³¹, 2³², 2⁶², 2⁶⁴−8, 1e20, 1e38, 1e39, …),
//! integers nudged (indices just out of range), strings replaced (hostile URIs, types), keys
//! removed, renamed or array elements duplicated, node cycles; then, on the bytes, truncation,
//! bit flips, duplicated ranges and u32 fields overwritten. URIs can name a decoy folder, FIFO,
//! symbolic link to /etc/passwd or device next to the scene.
//!
//! Runs:
//! - `cargo test --release -p photongrid --test fuzz_load`: 300 cases (fixed seed);
//! - `PHOTONGRID_FUZZ_SECONDS=60 cargo test --release -p photongrid --test fuzz_load -- --nocapture`:
//!   as many cases as fit in 60 s (seed from the clock unless `PHOTONGRID_FUZZ_SEED` is set);
//! - `PHOTONGRID_FUZZ_CASES=N` for another fixed number of cases.
//!
//! A failure prints the seed, the minimal mutations proptest shrank it to, and the path of the
//! failing input (copy it into the corpus and add a regression test in `hostile_scene.rs`).

use photongrid::scene::gltf::{load_with, LoadOptions};
use photongrid_testkit::*;
use proptest::prelude::*;
use proptest::test_runner::{Config, RngAlgorithm, TestCaseError, TestRng, TestRunner};
use serde_json::{json, Value};
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

/// Budget given to each load: hostile sizes must be refused, not allocated.
const BUDGET: u64 = 512 << 20;
/// Longest a single load may take.
const MAX_LOAD: Duration = Duration::from_secs(20);
/// Highest peak resident memory the whole run may reach.
const MAX_PEAK_RSS: u64 = 3 << 30;

const NUMBERS: &[f64] = &[
    0.0,
    -1.0,
    1.0,
    3.0,
    4.0,
    7.0,
    255.0,
    65536.0,
    2147483647.0,
    2147483648.0,
    4294967295.0,
    4294967296.0,
    4611686018427387904.0,
    18446744073709551608.0,
    1e20,
    -1e20,
    1e38,
    3.4e38,
    1e39,
    -1e39,
    1e-30,
    0.5,
    5120.0,
    5121.0,
    5122.0,
    5123.0,
    5125.0,
    5126.0,
];

const STRINGS: &[&str] = &[
    "",
    "data:",
    "data:application/octet-stream;base64,",
    "data:application/octet-stream;base64,!!!!",
    "data:image/png;base64,iVBORw0KGgo=",
    "%ff.bin",
    "a%00.bin",
    "%2e%2e/%2e%2e/etc/passwd",
    "file:/etc/passwd",
    "../../etc/passwd",
    "/etc/passwd",
    "/dev/zero",
    "/dev/urandom",
    "dir.bin",
    "pipe.bin",
    "link.bin",
    "decoy.bin",
    "missing.bin",
    "image/png",
    "image/jpeg",
    "VEC2",
    "VEC3",
    "SCALAR",
    "MAT4",
    "perspective",
    "orthographic",
    "spot",
    "directional",
];

const KEYS: &[&str] = &[
    "POSITION",
    "NORMAL",
    "TEXCOORD_0",
    "TEXCOORD_1",
    "COLOR_0",
    "JOINTS_0",
    "indices",
    "bufferView",
    "byteStride",
    "byteOffset",
    "count",
    "children",
    "mesh",
    "camera",
    "matrix",
    "scale",
    "sparse",
    "uri",
    "mimeType",
];

#[derive(Clone, Debug)]
enum Mutation {
    /// Set the `pick`-th JSON value to `NUMBERS[value]`.
    Number { pick: usize, value: usize },
    /// Add `delta` to the `pick`-th integer.
    Nudge { pick: usize, delta: i64 },
    /// Set the `pick`-th JSON value to `STRINGS[value]`.
    Text { pick: usize, value: usize },
    /// Remove the `pick`-th value from its object or array.
    Remove { pick: usize },
    /// Append a copy of an element to its array.
    Duplicate { pick: usize },
    /// Rename the key of the `pick`-th value to `KEYS[key]`.
    Rename { pick: usize, key: usize },
    /// `nodes[a].children = [b]`, `nodes[b].children = [a]`.
    Cycle { a: usize, b: usize },
    /// Keep the first fraction of the bytes.
    Truncate { keep: f64 },
    /// XOR a byte.
    Flip { at: f64, mask: u8 },
    /// Copy a range of bytes over another place.
    Splice { from: f64, to: f64, len: usize },
    /// Overwrite 4 bytes with an extreme little-endian u32.
    Patch { at: f64, value: u32 },
}

/// Mutations of the JSON document.
fn json_mutation() -> impl Strategy<Value = Mutation> {
    prop_oneof![
        5 => (any::<usize>(), 0..NUMBERS.len()).prop_map(|(pick, value)| Mutation::Number { pick, value }),
        4 => (any::<usize>(), -3i64..4).prop_map(|(pick, delta)| Mutation::Nudge { pick, delta }),
        2 => (any::<usize>(), 0..STRINGS.len()).prop_map(|(pick, value)| Mutation::Text { pick, value }),
        2 => any::<usize>().prop_map(|pick| Mutation::Remove { pick }),
        1 => any::<usize>().prop_map(|pick| Mutation::Duplicate { pick }),
        1 => (any::<usize>(), 0..KEYS.len()).prop_map(|(pick, key)| Mutation::Rename { pick, key }),
        1 => (0usize..8, 0usize..8).prop_map(|(a, b)| Mutation::Cycle { a, b }),
    ]
}

/// Mutations of the file's bytes.
fn byte_mutation() -> impl Strategy<Value = Mutation> {
    let frac = 0.0..1.0f64;
    prop_oneof![
        1 => frac.clone().prop_map(|keep| Mutation::Truncate { keep }),
        1 => (frac.clone(), 1u8..=255).prop_map(|(at, mask)| Mutation::Flip { at, mask }),
        1 => (frac.clone(), frac.clone(), 1usize..64).prop_map(|(from, to, len)| Mutation::Splice { from, to, len }),
        1 => (frac, prop::sample::select(vec![0, 1, 3, 12, 0x7fff_ffff, 0x8000_0000, 0xffff_fff8, u32::MAX]))
            .prop_map(|(at, value)| Mutation::Patch { at, value }),
    ]
}

/// One seed: a GLB (JSON document and binary chunk) or a .gltf document.
#[derive(Clone, Debug)]
struct Seed {
    name: String,
    doc: Value,
    bin: Option<Vec<u8>>,
}

fn seeds() -> Vec<Seed> {
    let mut files: Vec<PathBuf> = Vec::new();
    for dir in [
        repo_root().join("samples"),
        repo_root().join("crates/photongrid/fuzz-corpus"),
    ] {
        let mut found: Vec<PathBuf> = std::fs::read_dir(&dir)
            .unwrap_or_else(|e| panic!("{}: {e}", dir.display()))
            .map(|e| e.unwrap().path())
            .filter(|p| matches!(p.extension().and_then(|e| e.to_str()), Some("glb" | "gltf")))
            .collect();
        found.sort();
        files.extend(found);
    }
    let seeds: Vec<Seed> = files
        .iter()
        .filter_map(|p| {
            let bytes = std::fs::read(p).ok()?;
            let name = p.file_name()?.to_str()?.to_string();
            match glb_parts(&bytes) {
                Some((doc, bin)) => Some(Seed {
                    name,
                    doc,
                    bin: Some(bin),
                }),
                None => Some(Seed {
                    name,
                    doc: serde_json::from_slice(&bytes).ok()?,
                    bin: None,
                }),
            }
        })
        .collect();
    assert!(
        seeds.len() >= 10,
        "expected the samples and the corpus, found {} seeds",
        seeds.len()
    );
    seeds
}

/// Paths to every value of a document (object keys and array indices), with the value's kind.
fn paths(v: &Value, prefix: &mut Vec<Value>, out: &mut Vec<(Vec<Value>, Kind)>) {
    let kind = match v {
        Value::Number(n) if n.is_u64() => Kind::Integer,
        Value::Number(_) => Kind::Number,
        Value::String(_) => Kind::Text,
        _ => Kind::Other,
    };
    out.push((prefix.clone(), kind));
    match v {
        Value::Object(m) => {
            for (k, x) in m {
                prefix.push(json!(k));
                paths(x, prefix, out);
                prefix.pop();
            }
        }
        Value::Array(a) => {
            for (i, x) in a.iter().enumerate() {
                prefix.push(json!(i));
                paths(x, prefix, out);
                prefix.pop();
            }
        }
        _ => {}
    }
}

fn at_mut<'a>(v: &'a mut Value, path: &[Value]) -> Option<&'a mut Value> {
    path.iter().try_fold(v, |v, seg| match seg {
        Value::String(k) => v.get_mut(k.as_str()),
        Value::Number(i) => v.get_mut(i.as_u64()? as usize),
        _ => None,
    })
}

fn number(x: f64) -> Value {
    if x.fract() == 0.0 && (0.0..1.9e19).contains(&x) {
        json!(x as u64)
    } else if x.fract() == 0.0 && x < 0.0 && x > -1e18 {
        json!(x as i64)
    } else {
        json!(x)
    }
}

#[derive(Clone, Copy, PartialEq)]
enum Kind {
    Integer,
    Number,
    Text,
    Other,
}

fn mutate_json(doc: &mut Value, m: &Mutation) {
    let mut all = Vec::new();
    paths(doc, &mut Vec::new(), &mut all);
    let pick = |p: usize| all[p % all.len()].0.clone();
    // Numbers mostly replace numbers and strings strings, so that most files still parse.
    let typed = |p: usize, kinds: &[Kind]| {
        let some: Vec<&Vec<Value>> = all.iter().filter(|(_, k)| kinds.contains(k)).map(|(p, _)| p).collect();
        match (p % 8, some.is_empty()) {
            (0, _) | (_, true) => pick(p),
            _ => some[p % some.len()].clone(),
        }
    };
    match *m {
        Mutation::Number { pick: p, value } => {
            if let Some(v) = at_mut(doc, &typed(p, &[Kind::Integer, Kind::Number])) {
                *v = number(NUMBERS[value]);
            }
        }
        Mutation::Nudge { pick: p, delta } => {
            if let Some(v) = at_mut(doc, &typed(p, &[Kind::Integer])) {
                if let Some(n) = v.as_u64() {
                    *v = json!(n.saturating_add_signed(delta));
                }
            }
        }
        Mutation::Text { pick: p, value } => {
            if let Some(v) = at_mut(doc, &typed(p, &[Kind::Text])) {
                *v = json!(STRINGS[value]);
            }
        }
        Mutation::Remove { pick: p } | Mutation::Duplicate { pick: p } | Mutation::Rename { pick: p, .. } => {
            let path = pick(p);
            let Some((last, parent)) = path.split_last() else {
                return;
            };
            let Some(parent) = at_mut(doc, parent) else {
                return;
            };
            match (m, parent, last) {
                (Mutation::Remove { .. }, Value::Object(o), Value::String(k)) => {
                    o.remove(k);
                }
                (Mutation::Remove { .. }, Value::Array(a), Value::Number(i)) => {
                    a.remove(i.as_u64().unwrap() as usize);
                }
                (Mutation::Duplicate { .. }, Value::Array(a), Value::Number(i)) => {
                    let x = a[i.as_u64().unwrap() as usize].clone();
                    a.push(x);
                }
                (Mutation::Rename { key, .. }, Value::Object(o), Value::String(k)) => {
                    if let Some(x) = o.remove(k) {
                        o.insert(KEYS[*key].to_string(), x);
                    }
                }
                _ => {}
            }
        }
        Mutation::Cycle { a, b } => {
            // Only between nodes that are still objects (an earlier mutation may have replaced
            // the list or a node by something else).
            let Some(nodes) = doc.get_mut("nodes").and_then(Value::as_array_mut) else {
                return;
            };
            let n = nodes.len();
            if n > 0 && nodes[a % n].is_object() && nodes[b % n].is_object() {
                let (a, b) = (a % n, b % n);
                nodes[a]["children"] = json!([b]);
                nodes[b]["children"] = json!([a]);
            }
        }
        _ => {}
    }
}

fn mutate_bytes(bytes: &mut Vec<u8>, m: &Mutation) {
    let n = bytes.len();
    if n == 0 {
        return;
    }
    let at = |f: f64| ((f * n as f64) as usize).min(n - 1);
    match *m {
        Mutation::Truncate { keep } => bytes.truncate(at(keep)),
        Mutation::Flip { at: f, mask } => bytes[at(f)] ^= mask,
        Mutation::Splice { from, to, len } => {
            let (from, to) = (at(from), at(to));
            let chunk: Vec<u8> = bytes[from..(from + len).min(n)].to_vec();
            let end = (to + chunk.len()).min(n);
            bytes[to..end].copy_from_slice(&chunk[..end - to]);
        }
        Mutation::Patch { at: f, value } => {
            let i = at(f).min(n.saturating_sub(4));
            let end = (i + 4).min(n);
            bytes[i..end].copy_from_slice(&value.to_le_bytes()[..end - i]);
        }
        _ => {}
    }
}

/// The file a seed and its mutations give.
fn build(seed: &Seed, mutations: &[Mutation]) -> Vec<u8> {
    let mut doc = seed.doc.clone();
    for m in mutations {
        mutate_json(&mut doc, m);
    }
    let mut bytes = match &seed.bin {
        Some(bin) => glb_bytes(&doc, bin),
        None => serde_json::to_vec(&doc).unwrap(),
    };
    for m in mutations {
        mutate_bytes(&mut bytes, m);
    }
    bytes
}

/// A folder with the decoys hostile URIs may name.
fn workspace() -> TempDir {
    let dir = TempDir::new("fuzz");
    std::fs::write(dir.join("decoy.bin"), vec![7u8; 4096]).unwrap();
    std::fs::create_dir_all(dir.join("dir.bin")).unwrap();
    #[cfg(unix)]
    {
        let _ = std::os::unix::fs::symlink("/etc/passwd", dir.join("link.bin"));
        let _ = std::process::Command::new("mkfifo").arg(dir.join("pipe.bin")).status();
    }
    dir
}

/// Peak resident memory of this process (VmHWM), in bytes.
fn peak_rss() -> Option<u64> {
    let status = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = status.lines().find(|l| l.starts_with("VmHWM:"))?;
    Some(line.split_whitespace().nth(1)?.parse::<u64>().ok()? * 1024)
}

#[derive(Default)]
struct Tally {
    cases: usize,
    loaded: usize,
    refused: std::collections::BTreeMap<String, usize>,
    slowest: Duration,
}

/// Load one mutated file and check the properties.
fn check(dir: &Path, seed: &Seed, bytes: &[u8], external: bool, tally: &mut Tally) -> Result<(), TestCaseError> {
    let ext = if seed.bin.is_some() { "glb" } else { "gltf" };
    let path = dir.join(format!("case.{ext}"));
    std::fs::write(&path, bytes).unwrap();
    let options = LoadOptions {
        allow_external_uris: external,
        memory_budget_bytes: Some(BUDGET),
    };
    let start = Instant::now();
    let result = load_with(&path, &options);
    let took = start.elapsed();
    tally.cases += 1;
    tally.slowest = tally.slowest.max(took);
    let keep = |why: &str| {
        let failure = std::env::temp_dir().join(format!("photongrid-fuzz-failure-{}.{ext}", std::process::id()));
        std::fs::write(&failure, bytes).unwrap();
        TestCaseError::fail(format!(
            "{why} (seed {}; input saved as {})",
            seed.name,
            failure.display()
        ))
    };
    if took > MAX_LOAD {
        return Err(keep(&format!("the load took {took:?}")));
    }
    match result {
        Ok(_) => tally.loaded += 1,
        Err(e) => {
            let message = e.to_string();
            if message.contains("internal error") {
                return Err(keep(&format!("a panic was caught by the loader's net: {message}")));
            }
            if !message.contains("case.") {
                return Err(keep(&format!("the message does not name the file: {message}")));
            }
            if std::env::var_os("PHOTONGRID_FUZZ_VERBOSE").is_some() {
                eprintln!("{}: {message}", seed.name);
            }
            let kind = message.split(": ").nth(1).unwrap_or("?");
            let kind: String = kind.chars().take_while(|c| *c != '[').collect();
            *tally.refused.entry(kind).or_default() += 1;
        }
    }
    if let Some(peak) = peak_rss() {
        if peak > MAX_PEAK_RSS {
            return Err(keep(&format!("peak memory reached {peak} bytes")));
        }
    }
    Ok(())
}

fn env_u64(name: &str) -> Option<u64> {
    std::env::var(name).ok().and_then(|v| v.parse().ok())
}

#[test]
fn load_never_panics_hangs_or_blows_up() {
    let seeds = seeds();
    let dir = workspace();
    let seconds = env_u64("PHOTONGRID_FUZZ_SECONDS");
    let seed = env_u64("PHOTONGRID_FUZZ_SEED").unwrap_or_else(|| match seconds {
        Some(_) => std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map(|d| d.as_secs())
            .unwrap_or(1),
        None => 12,
    });
    let (cases_per_round, deadline) = match seconds {
        Some(s) => (64, Some(Instant::now() + Duration::from_secs(s))),
        None => (env_u64("PHOTONGRID_FUZZ_CASES").unwrap_or(300) as u32, None),
    };
    eprintln!("fuzz_load: {} seeds, PHOTONGRID_FUZZ_SEED={seed}", seeds.len());
    let strategy = (
        0..seeds.len(),
        prop::collection::vec(json_mutation(), 1..5),
        prop::option::weighted(0.25, prop::collection::vec(byte_mutation(), 1..3)),
        any::<bool>(),
    );
    let tally = std::cell::RefCell::new(Tally::default());
    for round in 0u64.. {
        let mut key = [0u8; 32];
        key[..8].copy_from_slice(&seed.to_le_bytes());
        key[8..16].copy_from_slice(&round.to_le_bytes());
        let config = Config {
            cases: cases_per_round,
            failure_persistence: None,
            max_shrink_iters: 200,
            ..Config::default()
        };
        let mut runner = TestRunner::new_with_rng(config, TestRng::from_seed(RngAlgorithm::ChaCha, &key));
        let result = runner.run(&strategy, |(s, mut mutations, bytes, external)| {
            mutations.extend(bytes.into_iter().flatten());
            let bytes = build(&seeds[s], &mutations);
            check(dir.path(), &seeds[s], &bytes, external, &mut tally.borrow_mut())
        });
        if let Err(e) = result {
            panic!("fuzz_load failed (PHOTONGRID_FUZZ_SEED={seed}, round {round}): {e}");
        }
        if deadline.is_none_or(|d| Instant::now() >= d) {
            break;
        }
    }
    let tally = tally.into_inner();
    eprintln!(
        "fuzz_load: {} cases, {} loaded, slowest load {:?}, peak memory {} MiB; refused: {:?}",
        tally.cases,
        tally.loaded,
        tally.slowest,
        peak_rss().unwrap_or(0) >> 20,
        tally.refused
    );
}

/// Append `bytes` to the buffer (4-byte aligned) as a new bufferView; returns its index.
fn push_view(doc: &mut Value, bin: &mut Vec<u8>, bytes: &[u8]) -> usize {
    while !bin.len().is_multiple_of(4) {
        bin.push(0);
    }
    let offset = bin.len();
    bin.extend_from_slice(bytes);
    doc["buffers"][0]["byteLength"] = json!(bin.len());
    let views = doc["bufferViews"].as_array_mut().unwrap();
    views.push(json!({"buffer": 0, "byteOffset": offset, "byteLength": bytes.len()}));
    views.len() - 1
}

/// The seed corpus: small files covering what the loader reads (GLB and .gltf, embedded and
/// data: images, sparse accessors, instancing, strips and fans, u8 indices, every light and
/// camera kind, glass, mirror, emission, matrices). Regenerate with
/// `cargo test --release -p photongrid --test fuzz_load -- --ignored write_seed_corpus`.
#[test]
#[ignore]
fn write_seed_corpus() {
    let dir = repo_root().join("crates/photongrid/fuzz-corpus");
    std::fs::create_dir_all(&dir).unwrap();
    let base = hostile_base();
    base.write_glb(&dir, "base.glb");
    base.write_gltf(&dir, "base_embedded.gltf");
    simple_scene(100.0).write_glb(&dir, "simple.glb");

    // A texture in a bufferView and one as a data: URI.
    let (mut doc, mut bin) = (base.json(&BufferMode::Glb), base.bin().to_vec());
    let png = png_bytes(4, 4, 3, &[128; 48]);
    let v = push_view(&mut doc, &mut bin, &png);
    let data_uri = format!("data:image/png;base64,{}", base64(&png_bytes(2, 2, 4, &[200; 16])));
    doc["images"] = json!([{ "bufferView": v, "mimeType": "image/png" }, { "uri": data_uri }]);
    doc["samplers"] = json!([{ "wrapS": 33071 }]);
    doc["textures"] = json!([{ "source": 0, "sampler": 0 }, { "source": 1 }]);
    doc["materials"][0]["pbrMetallicRoughness"]["baseColorTexture"] = json!({ "index": 0 });
    doc["materials"][0]["normalTexture"] = json!({ "index": 1 });
    std::fs::write(dir.join("textured.glb"), glb_bytes(&doc, &bin)).unwrap();

    // Sparse accessors: one over a bufferView, one without (zeros plus the sparse values).
    let (mut doc, mut bin) = (base.json(&BufferMode::Glb), base.bin().to_vec());
    let idx = push_view(&mut doc, &mut bin, &[1, 0, 3, 0]);
    let val: Vec<u8> = [0.0f32, 0.1, 0.0, 0.0, 0.2, 0.0]
        .iter()
        .flat_map(|f| f.to_le_bytes())
        .collect();
    let vals = push_view(&mut doc, &mut bin, &val);
    let sparse =
        json!({"count": 2, "indices": {"bufferView": idx, "componentType": 5123}, "values": {"bufferView": vals}});
    doc["accessors"][0]["sparse"] = sparse.clone();
    doc["accessors"][4]["sparse"] = sparse;
    doc["accessors"][4].as_object_mut().unwrap().remove("bufferView");
    std::fs::write(dir.join("sparse.glb"), glb_bytes(&doc, &bin)).unwrap();

    // Instancing: 3 levels of 3 children over one small mesh.
    let mut g = hostile_base();
    let leaf = g.mesh(vec![uv_sphere([0.0, 0.5, 0.0], 0.2, 3, 4)]);
    let mut next = g.node(Node {
        mesh: Some(leaf),
        transform: Transform::translation([0.3, 0.0, 0.0]),
        ..Default::default()
    });
    for _ in 0..3 {
        next = g.node(Node {
            children: vec![next; 3],
            ..Default::default()
        });
    }
    g.add_root(next);
    g.write_glb(&dir, "instancing.glb");

    // Strips, fans, u8 indices, every light and camera kind, glass, mirror, emission, matrix.
    let mut g = simple_scene(50.0);
    let glass = g.material(Material::glass(Some(1.45)));
    let mirror = g.material(Material {
        metallic: 1.0,
        roughness: 0.0,
        ..Default::default()
    });
    let glow = g.material(Material::emitter([1.0, 0.8, 0.5], Some(20.0)));
    let quad = vec![[0.0, 1.0, 0.0], [1.0, 1.0, 0.0], [0.0, 1.0, 1.0], [1.0, 1.0, 1.0]];
    let strip = Prim::new(quad.clone()).mode(mode::TRIANGLE_STRIP).material(glass);
    let fan = Prim::new(quad.clone())
        .mode(mode::TRIANGLE_FAN)
        .indices_u32(vec![0, 1, 3, 2])
        .material(mirror);
    let lines = Prim::new(quad).mode(mode::LINES);
    let m = g.mesh(vec![strip, fan, lines, floor_quad(0.3, 2.0).material(glow)]);
    g.root(Node {
        mesh: Some(m),
        transform: Transform::Matrix([
            1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, -1.0, 0.0, 0.5, 0.0, 0.0, 1.0,
        ]),
        ..Default::default()
    });
    for light in [Light::spot(300.0, 0.3, 0.6), Light::directional(2.0)] {
        let l = g.light(light);
        g.root(Node {
            light: Some(l),
            transform: Transform::tr([0.0, 4.0, 0.0], look_down()),
            ..Default::default()
        });
    }
    let c = g.camera(Camera::Orthographic { xmag: 3.0, ymag: 2.0 });
    g.root(Node {
        camera: Some(c),
        transform: Transform::tr([0.0, 6.0, 0.0], look_down()),
        ..Default::default()
    });
    let mut doc = g.json(&BufferMode::Glb);
    let mut bin = g.bin().to_vec();
    let u8_indices = push_view(&mut doc, &mut bin, &[0, 1, 2]);
    let accessors = doc["accessors"].as_array_mut().unwrap();
    accessors.push(json!({"bufferView": u8_indices, "componentType": 5121, "count": 3, "type": "SCALAR"}));
    let a = accessors.len() - 1;
    doc["meshes"][0]["primitives"][0]["indices"] = json!(a);
    std::fs::write(dir.join("kinds.glb"), glb_bytes(&doc, &bin)).unwrap();
    for entry in std::fs::read_dir(&dir).unwrap() {
        let p = entry.unwrap().path();
        let size = std::fs::metadata(&p).unwrap().len();
        assert!(size < 16_000, "{} is {size} bytes: keep the corpus small", p.display());
        let loaded = load_with(&p, &LoadOptions::default());
        eprintln!(
            "{}: {size} bytes, {}",
            p.display(),
            loaded
                .map(|s| format!("{} triangles", s.triangles.len()))
                .unwrap_or_else(|e| e.to_string())
        );
    }
}
