//! The viewer in a real browser: Debian's Chromium, headless, software WebGL. For a synthetic
//! sphere and DiLiGenT cat, a screenshot of the relit view with the light set through the URL
//! must match the library's relighting of the same normals and albedo (mean absolute difference
//! ≤ 2/255 per channel over the object); the layer switch and the probe are driven through the
//! URL fragment and read back from the page's state (`<pre id="ps-state">`, printed by
//! `--dump-dom`), and checked against the arrays of the output folder. The page must load no
//! remote resource. `view --serve` is checked with bounded requests to 127.0.0.1.
//!
//! Needs `/usr/bin/chromium`: without it the browser tests print SKIPPED and pass, unless the
//! environment variable `CI` is set, in which case they fail (`.ci/run` installs it).

use photostereo::io::figure::colormap;
use photostereo::io::viewer::{albedo_white, relight, RelightParams};
use photostereo::solve::metrics::angular_error_deg;
use serde_json::Value;
use std::io::{BufRead, BufReader, Read, Write};
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

const BIN: &str = env!("CARGO_BIN_EXE_photostereo");
const CHROMIUM: &str = "/usr/bin/chromium";

fn data(rel: &str) -> PathBuf {
    PathBuf::from(concat!(env!("CARGO_MANIFEST_DIR"), "/../../../shared/data")).join(rel)
}

/// The browser, or `None` (test skipped) when it is missing outside CI.
fn chromium() -> Option<&'static str> {
    if Path::new(CHROMIUM).exists() {
        return Some(CHROMIUM);
    }
    if std::env::var_os("CI").is_some() {
        panic!("{CHROMIUM} is missing and CI is set: install Debian's chromium (.ci/run does)");
    }
    eprintln!(
        "SKIPPED: {CHROMIUM} not found; install Debian's `chromium` to run the browser tests \
         (with CI set, a missing browser is a failure)"
    );
    None
}

fn photostereo(args: &[&std::ffi::OsStr]) {
    let out = Command::new(BIN).args(args).output().unwrap();
    assert!(
        out.status.success(),
        "photostereo {:?}: {}",
        args,
        String::from_utf8_lossy(&out.stderr)
    );
}

/// What one headless Chromium run left behind.
struct Browser {
    stdout: String,
    stderr: String,
    netlog: String,
}

/// Runs Chromium on `url` with a fresh profile; `extra` adds `--screenshot=…` or `--dump-dom`.
fn browse(tmp: &Path, url: &str, size: (usize, usize), extra: &[String]) -> Browser {
    let profile = tempfile::tempdir_in(tmp).unwrap();
    let netlog = profile.path().join("netlog.json");
    let mut cmd = Command::new(CHROMIUM);
    cmd.args([
        "--headless",
        "--no-sandbox",
        "--disable-gpu",
        "--enable-unsafe-swiftshader",
        "--disable-quic",
        "--no-first-run",
        "--disable-background-networking",
        "--disable-component-update",
        "--disable-sync",
        "--disable-default-apps",
        "--disable-extensions",
        "--no-default-browser-check",
        // Belt and braces: no host name resolves, so whatever the browser still tries fails
        // at once (IP addresses, such as the server test's 127.0.0.1, are not names).
        "--host-resolver-rules=MAP * ~NOTFOUND",
        "--hide-scrollbars",
        "--force-device-scale-factor=1",
        "--enable-logging=stderr",
        "--v=0",
        "--virtual-time-budget=30000",
    ])
    .arg(format!(
        "--user-data-dir={}",
        profile.path().join("p").display()
    ))
    .arg(format!("--log-net-log={}", netlog.display()))
    .arg(format!("--window-size={},{}", size.0, size.1))
    .args(extra)
    .arg(url)
    .stdout(Stdio::piped())
    .stderr(Stdio::piped());
    let mut child = cmd.spawn().expect("starting chromium");
    let (mut so, mut se) = (child.stdout.take().unwrap(), child.stderr.take().unwrap());
    let t_out = std::thread::spawn(move || {
        let mut s = String::new();
        let _ = so.read_to_string(&mut s);
        s
    });
    let t_err = std::thread::spawn(move || {
        let mut s = String::new();
        let _ = se.read_to_string(&mut s);
        s
    });
    let deadline = Instant::now() + Duration::from_secs(180);
    loop {
        if child.try_wait().unwrap().is_some() {
            break;
        }
        if Instant::now() > deadline {
            let _ = child.kill();
            let _ = child.wait();
            panic!("chromium did not finish within 180 s on {url}");
        }
        std::thread::sleep(Duration::from_millis(50));
    }
    Browser {
        stdout: t_out.join().unwrap(),
        stderr: t_err.join().unwrap(),
        netlog: std::fs::read_to_string(&netlog).unwrap_or_default(),
    }
}

fn file_url(index: &Path, fragment: &str) -> String {
    format!(
        "file://{}#{fragment}",
        std::fs::canonicalize(index).unwrap().display()
    )
}

/// The page's state after loading `fragment`. Headless Chromium's virtual time does not wait
/// for every asynchronous image decode, so on a loaded machine the DOM can be dumped before the
/// page says it is ready: such a load is tried again (up to three times in all); a page error
/// fails at once.
fn page_state(tmp: &Path, index: &Path, fragment: &str) -> Value {
    let mut tries = 0;
    loop {
        tries += 1;
        let b = browse(
            tmp,
            &file_url(index, fragment),
            (1000, 700),
            &["--dump-dom".into()],
        );
        let start = b
            .stdout
            .find("<pre id=\"ps-state\"")
            .unwrap_or_else(|| panic!("no state in the page: {}", b.stderr));
        let body = &b.stdout[start..];
        let json = &body[body.find('>').unwrap() + 1..body.find("</pre>").unwrap()];
        let json = json
            .replace("&quot;", "\"")
            .replace("&lt;", "<")
            .replace("&gt;", ">")
            .replace("&amp;", "&");
        let v: Value = serde_json::from_str(&json).unwrap();
        assert_eq!(v["error"], Value::Null, "page error: {v}");
        if v["ready"] != true && tries < 3 {
            continue;
        }
        assert_eq!(v["ready"], true, "page not ready after {tries} loads: {v}");
        check_no_remote(&b);
        return v;
    }
}

/// A screenshot of `fragment` in a window of `size`, as RGB bytes.
fn screenshot(tmp: &Path, index: &Path, fragment: &str, size: (usize, usize)) -> Vec<[u8; 3]> {
    let shot = tmp.join(format!("shot-{}.png", fragment.len()));
    let b = browse(
        tmp,
        &file_url(index, fragment),
        size,
        &[format!("--screenshot={}", shot.display())],
    );
    check_no_remote(&b);
    let dec = png::Decoder::new(std::io::BufReader::new(std::fs::File::open(&shot).unwrap()));
    let mut reader = dec.read_info().unwrap();
    let mut buf = vec![0; reader.output_buffer_size().unwrap()];
    let info = reader.next_frame(&mut buf).unwrap();
    assert_eq!(
        (info.width as usize, info.height as usize),
        size,
        "screenshot size"
    );
    let ch = match info.color_type {
        png::ColorType::Rgb => 3,
        png::ColorType::Rgba => 4,
        c => panic!("screenshot colour type {c:?}"),
    };
    assert_eq!(info.bit_depth, png::BitDepth::Eight);
    buf[..info.buffer_size()]
        .chunks_exact(ch)
        .map(|p| [p[0], p[1], p[2]])
        .collect()
}

/// Chromium's console must not report a blocked (remote) load, and the page must have asked
/// the network for nothing (see [`page_requests`]).
fn check_no_remote(b: &Browser) {
    assert!(
        !b.stderr.contains("Content Security Policy"),
        "the page tried to load something its policy forbids:\n{}",
        b.stderr
    );
    let remote = page_requests(&b.netlog);
    assert!(remote.is_empty(), "the page requested {remote:?}");
}

/// The URLs of the network requests the page made, read from Chromium's network log.
///
/// Every request is logged as a `URL_REQUEST` source whose `URL_REQUEST_START_JOB` event
/// names the request's `initiator` and `network_isolation_key`. A request that a page (or its
/// workers) makes carries the page's origin as initiator (`"null"` for a `file:` page) and the
/// page's site in its isolation key; the browser's own background services (updates, time,
/// accounts, search suggestions) are made by no origin (`"not an origin"`) and are keyed to no
/// page. The request's source tells them apart, so no list of service hosts is needed. A log
/// cut short by a killed browser is read up to its last whole event.
fn page_requests(netlog: &str) -> Vec<String> {
    let log: Value = serde_json::from_str(netlog)
        .or_else(|_| {
            let whole = netlog.trim_end().trim_end_matches(',');
            let cut = whole.rfind("},").map_or(whole, |i| &whole[..i + 1]);
            serde_json::from_str(&format!("{cut}]}}"))
        })
        .unwrap_or_else(|e| panic!("Chromium's network log is unreadable ({e})"));
    let name = |table: &str, id: &Value| {
        log["constants"][table]
            .as_object()
            .and_then(|t| t.iter().find(|(_, v)| *v == id))
            .map(|(k, _)| k.clone())
            .unwrap_or_default()
    };
    let events = log["events"]
        .as_array()
        .expect("network log without events");
    let mut urls = Vec::new();
    for e in events {
        if name("logEventTypes", &e["type"]) != "URL_REQUEST_START_JOB" {
            continue;
        }
        let p = &e["params"];
        let url = p["url"].as_str().unwrap_or("");
        let initiator = p["initiator"].as_str().unwrap_or("not an origin");
        let isolation = p["network_isolation_key"].as_str().unwrap_or("");
        let from_page = initiator != "not an origin" || isolation.starts_with("file:");
        let local =
            url.starts_with("file:") || url.starts_with("data:") || url.starts_with("blob:");
        if from_page && !local {
            urls.push(url.to_string());
        }
    }
    urls
}

/// The written page and its data must name no remote address.
fn check_files_name_no_remote(folder: &Path) {
    let mut files = vec![folder.join("index.html")];
    let mut stack = vec![folder.join("view")];
    while let Some(d) = stack.pop() {
        for e in std::fs::read_dir(&d).unwrap() {
            let p = e.unwrap().path();
            if p.is_dir() {
                stack.push(p);
            } else {
                files.push(p);
            }
        }
    }
    for f in files {
        let text = std::fs::read_to_string(&f).unwrap();
        for bad in ["http://", "https://", "ftp://", "ws://", "wss://"] {
            assert!(!text.contains(bad), "{} names {bad}", f.display());
        }
    }
}

struct Arrays {
    w: usize,
    h: usize,
    normals: Vec<[f32; 3]>,
    albedo: Vec<f32>,
    channels: usize,
    mask: Vec<bool>,
    residual: Vec<f32>,
    status: Vec<u8>,
    lights: usize,
}

fn arrays(out: &Path) -> Arrays {
    let n: ndarray::Array3<f32> = ndarray_npy::read_npy(out.join("normals.npy")).unwrap();
    let (h, w, _) = n.dim();
    let normals: Vec<[f32; 3]> = n
        .iter()
        .copied()
        .collect::<Vec<_>>()
        .chunks_exact(3)
        .map(|v| [v[0], v[1], v[2]])
        .collect();
    let a: ndarray::Array3<f32> = ndarray_npy::read_npy(out.join("albedo.npy")).unwrap();
    let channels = a.dim().2;
    let r: ndarray::Array2<f32> = ndarray_npy::read_npy(out.join("residual.npy")).unwrap();
    let s: ndarray::Array3<u8> = ndarray_npy::read_npy(out.join("light_status.npy")).unwrap();
    Arrays {
        w,
        h,
        mask: normals.iter().map(|n| *n != [0.0; 3]).collect(),
        normals,
        albedo: a.iter().copied().collect(),
        channels,
        residual: r.iter().copied().collect(),
        lights: s.dim().0,
        status: s.iter().copied().collect(),
    }
}

/// Mean absolute difference per channel over the mask, in 1/255 units.
fn mad(a: &[[u8; 3]], b: &[[u8; 3]], mask: &[bool]) -> [f64; 3] {
    let mut s = [0f64; 3];
    let mut n = 0usize;
    for ((x, y), &m) in a.iter().zip(b).zip(mask) {
        if m {
            n += 1;
            for c in 0..3 {
                s[c] += (x[c] as f64 - y[c] as f64).abs();
            }
        }
    }
    s.map(|v| v / n.max(1) as f64)
}

/// Relit screenshot against the library, for `params` given in the URL.
fn check_relight(tmp: &Path, out: &Path, a: &Arrays, p: RelightParams, name: &str) -> [f64; 3] {
    let frag = format!(
        "plain=1&layer=relight&light={},{},{}&exposure={}&specular={}&shininess={}&ambient={}",
        p.light[0], p.light[1], p.light[2], p.exposure, p.specular, p.shininess, p.ambient
    );
    let shot = screenshot(tmp, &out.join("index.html"), &frag, (a.w, a.h));
    let want = relight(&a.normals, &a.albedo, a.channels, &p);
    let d = mad(&shot, &want, &a.mask);
    eprintln!("{name}: relit screenshot vs library, mean |Δ| per channel (1/255): {d:.3?}");
    for c in d {
        assert!(c <= 2.0, "{name}: mean absolute difference {d:?} > 2/255");
    }
    // The object really is lit (not an empty screenshot) and the background stays black.
    let lit = shot
        .iter()
        .zip(&a.mask)
        .filter(|(s, &m)| m && s[0] > 20)
        .count();
    assert!(lit > a.mask.iter().filter(|&&m| m).count() / 4);
    d
}

fn params(a: &Arrays, light: [f32; 3]) -> RelightParams {
    RelightParams {
        light,
        white: albedo_white(&a.albedo, a.channels, &a.mask),
        ..Default::default()
    }
}

/// The layer switch (normals, the status of the light with most shadows, unusable count, error)
/// and the probe, through the URL fragment, against the output folder's arrays.
fn check_layers_and_probe(tmp: &Path, out: &Path, a: &Arrays, gt: &Path) {
    let index = out.join("index.html");
    let hw = a.w * a.h;
    // Layer switch: the normal map, drawn 1:1.
    let shot = screenshot(tmp, &index, "plain=1&layer=normals", (a.w, a.h));
    let want: Vec<[u8; 3]> = a
        .normals
        .iter()
        .map(|n| n.map(|v| (((v + 1.0) * 0.5) * 255.0).round() as u8))
        .collect();
    let d = mad(&shot, &want, &a.mask);
    assert!(d.iter().all(|&c| c <= 1.0), "normals layer: {d:?}");

    // Layer switch: the status of the light with the most shadowed pixels.
    let k = (0..a.lights)
        .max_by_key(|&k| {
            a.status[k * hw..(k + 1) * hw]
                .iter()
                .filter(|&&s| s == 1)
                .count()
        })
        .unwrap();
    let shot = screenshot(
        tmp,
        &index,
        &format!("plain=1&layer=status&k={}", k + 1),
        (a.w, a.h),
    );
    let colours: [[i32; 3]; 4] = [[61, 143, 77], [36, 66, 173], [255, 214, 0], [219, 41, 41]];
    let (mut agree, mut total) = (0usize, 0usize);
    for i in (0..hw).filter(|&i| a.mask[i]) {
        let s = shot[i].map(|v| v as i32);
        let code = (0..4)
            .min_by_key(|&c| (0..3).map(|j| (s[j] - colours[c][j]).pow(2)).sum::<i32>())
            .unwrap();
        let want = match a.status[k * hw + i] {
            0 => 0,
            1 => 1,
            2 => 2,
            _ => 3,
        };
        total += 1;
        agree += (code == want) as usize;
    }
    assert_eq!(agree, total, "status layer of light {}", k + 1);

    // The probe, on the pixel with the most unusable lights, in the count layer.
    let count = |i: usize| {
        (0..a.lights)
            .filter(|&k| !matches!(a.status[k * hw + i], 0 | 255))
            .count()
    };
    let worst = (0..hw)
        .filter(|&i| a.mask[i])
        .max_by_key(|&i| count(i))
        .unwrap();
    let truth = photostereo::io::groundtruth::read_normal_map(gt).unwrap();
    let inside = a.mask.iter().filter(|&&m| m).count();
    let middle = (0..hw).filter(|&i| a.mask[i]).nth(inside / 2).unwrap();
    for (i, layer) in [(worst, "count"), (middle, "error")] {
        assert!(a.mask[i], "probe pixel inside the object");
        let (row, col) = (i / a.w, i % a.w);
        let st = page_state(
            tmp,
            &index,
            &format!("layer={layer}&probe={row},{col}&fit=1:1"),
        );
        assert_eq!(st["layer"], layer);
        let pr = &st["probe"];
        assert_eq!(
            (pr["row"].as_u64(), pr["col"].as_u64()),
            (Some(row as u64), Some(col as u64))
        );
        assert_eq!(pr["inside"], true);
        for c in 0..3 {
            let got = pr["normal"][c].as_f64().unwrap();
            assert!((got - a.normals[i][c] as f64).abs() < 4e-5, "normal {pr}");
            let alb = pr["albedo"][c].as_f64().unwrap();
            let want = a.albedo[i * a.channels + c] as f64;
            assert!(
                (alb - want).abs() < 1e-4 * want.max(1e-2) + 2e-5,
                "albedo {pr}"
            );
        }
        let res = pr["residual"].as_f64().unwrap();
        assert!(
            (res - a.residual[i] as f64).abs() <= 1e-6 * res.abs().max(1.0),
            "residual"
        );
        assert_eq!(pr["unusable"].as_u64(), Some(count(i) as u64));
        for (code, name) in [(1u8, "shadow"), (2, "highlight"), (0, "used")] {
            let want: Vec<u64> = (0..a.lights)
                .filter(|&k| a.status[k * hw + i] == code)
                .map(|k| k as u64 + 1)
                .collect();
            let got: Vec<u64> = pr["lights"][name]
                .as_array()
                .unwrap()
                .iter()
                .map(|v| v.as_u64().unwrap())
                .collect();
            assert_eq!(got, want, "{name} lights at ({row}, {col})");
        }
        let err = angular_error_deg(a.normals[i], truth.normals[i]);
        assert!(
            (pr["error_deg"].as_f64().unwrap() - err).abs() < 1e-3,
            "error {pr}"
        );
        // The colour the layer drew at the probe (1:1 view: one pixel, no filtering).
        let rgba: Vec<i64> = pr["rgba"]
            .as_array()
            .unwrap()
            .iter()
            .map(|v| v.as_i64().unwrap())
            .collect();
        let want = match layer {
            "count" => colormap(count(i) as f32 / a.lights as f32),
            _ => colormap(err as f32 / 45.0),
        };
        for c in 0..3 {
            assert!(
                (rgba[c] - want[c] as i64).abs() <= 2,
                "{layer} colour {rgba:?} vs {want:?}"
            );
        }
    }
    // Outside the object, when there is an outside.
    if let Some(outside) = (0..hw).find(|&i| !a.mask[i]) {
        let st = page_state(
            tmp,
            &index,
            &format!("probe={},{}", outside / a.w, outside % a.w),
        );
        assert_eq!(st["probe"]["inside"], false);
    }
}

#[test]
fn sphere_relit_layers_and_probe_in_the_browser_match_the_library() {
    let Some(_) = chromium() else { return };
    let t0 = Instant::now();
    let tmp = tempfile::tempdir().unwrap();
    let cap = tmp.path().join("sphere");
    let out = tmp.path().join("out");
    photostereo(&[
        "synth".as_ref(),
        "sphere".as_ref(),
        "--rig".as_ref(),
        "ring8".as_ref(),
        "--size".as_ref(),
        "160".as_ref(),
        "--brdf".as_ref(),
        "lambert".as_ref(),
        "-o".as_ref(),
        cap.as_os_str(),
        "-q".as_ref(),
    ]);
    photostereo(&[
        "run".as_ref(),
        cap.as_os_str(),
        "--gt".as_ref(),
        cap.join("gt/normal.npy").as_os_str(),
        "--view".as_ref(),
        "-o".as_ref(),
        out.as_os_str(),
        "-q".as_ref(),
    ]);
    check_files_name_no_remote(&out);
    let a = arrays(&out);
    // A raking light from the right and above, then a frontal one with a specular highlight.
    let p = params(&a, [0.8, 0.3, 0.52]);
    check_relight(tmp.path(), &out, &a, p, "sphere, raking");
    let p = RelightParams {
        exposure: -0.5,
        specular: 0.3,
        shininess: 25.0,
        ambient: 0.1,
        ..params(&a, [-0.2, -0.1, 0.97])
    };
    check_relight(tmp.path(), &out, &a, p, "sphere, specular");
    // The recursive method found shadows: the status layer and the probe have something to show.
    assert!(a.status.contains(&1), "no shadowed light on the sphere");
    check_layers_and_probe(tmp.path(), &out, &a, &cap.join("gt/normal.npy"));
    eprintln!("sphere browser test: {:.1} s", t0.elapsed().as_secs_f64());
}

#[test]
fn cat_relit_layers_and_probe_in_the_browser_match_the_arrays() {
    let Some(_) = chromium() else { return };
    let t0 = Instant::now();
    let tmp = tempfile::tempdir().unwrap();
    let dir = data("diligent/catPNG");
    let out = tmp.path().join("cat");
    let gt = dir.join("Normal_gt.mat");
    photostereo(&[
        "run".as_ref(),
        dir.as_os_str(),
        "--method".as_ref(),
        "l2".as_ref(),
        "--gt".as_ref(),
        gt.as_os_str(),
        "-o".as_ref(),
        out.as_os_str(),
        "-q".as_ref(),
    ]);
    photostereo(&[
        "view".as_ref(),
        out.as_os_str(),
        "--lights".as_ref(),
        dir.join("light_directions.txt").as_os_str(),
        "-q".as_ref(),
    ]);
    check_files_name_no_remote(&out);
    let index = out.join("index.html");
    let a = arrays(&out);

    // Relighting, light through the URL.
    let p = params(&a, [-0.45, 0.6, 0.66]);
    check_relight(tmp.path(), &out, &a, p, "cat");

    check_layers_and_probe(tmp.path(), &out, &a, &gt);
    // The 3D view loads its mesh.
    let st = page_state(tmp.path(), &index, "layer=mesh");
    assert_eq!(st["mesh"], "ready");
    eprintln!("cat browser test: {:.1} s", t0.elapsed().as_secs_f64());
}

/// The network check must fail a page that loads a remote resource: a bare page with a remote
/// image and a `fetch` is caught in the network log, and the viewer's own page with a remote
/// image injected is caught (its policy blocks the load and the console says so).
#[test]
fn a_page_that_loads_a_remote_resource_fails_the_check() {
    let Some(_) = chromium() else { return };
    let tmp = tempfile::tempdir().unwrap();
    let bare = tmp.path().join("bare.html");
    std::fs::write(
        &bare,
        "<!DOCTYPE html><p>bare</p><img src=\"https://example.com/remote.png\">\
         <script>fetch('https://example.org/remote.json').catch(() => {});</script>",
    )
    .unwrap();
    let b = browse(
        tmp.path(),
        &file_url(&bare, ""),
        (200, 200),
        &["--dump-dom".into()],
    );
    assert!(
        b.stdout.contains("bare"),
        "the page did not load: {}",
        b.stderr
    );
    let urls = page_requests(&b.netlog);
    assert!(
        urls.iter().any(|u| u == "https://example.com/remote.png")
            && urls.iter().any(|u| u == "https://example.org/remote.json"),
        "the page's remote requests were not found in the network log: {urls:?}"
    );
    assert!(std::panic::catch_unwind(|| check_no_remote(&b)).is_err());

    // The viewer's page, with a remote image injected after its body tag.
    let cap = tmp.path().join("sphere");
    let out = tmp.path().join("out");
    photostereo(&[
        "synth".as_ref(),
        "sphere".as_ref(),
        "--rig".as_ref(),
        "ring8".as_ref(),
        "--size".as_ref(),
        "48".as_ref(),
        "-o".as_ref(),
        cap.as_os_str(),
        "-q".as_ref(),
    ]);
    photostereo(&[
        "run".as_ref(),
        cap.as_os_str(),
        "--view".as_ref(),
        "-o".as_ref(),
        out.as_os_str(),
        "-q".as_ref(),
    ]);
    let index = out.join("index.html");
    let clean = browse(
        tmp.path(),
        &file_url(&index, "plain=1"),
        (200, 200),
        &["--dump-dom".into()],
    );
    check_no_remote(&clean);
    let page = std::fs::read_to_string(&index).unwrap();
    let at = page.find("<body").expect("the viewer page has a body");
    let at = at + page[at..].find('>').unwrap() + 1;
    let injected = format!(
        "{}<img src=\"https://example.com/injected.png\">{}",
        &page[..at],
        &page[at..]
    );
    std::fs::write(&index, injected).unwrap();
    let b = browse(
        tmp.path(),
        &file_url(&index, "plain=1"),
        (200, 200),
        &["--dump-dom".into()],
    );
    assert!(
        b.stdout.contains("injected.png"),
        "not injected: {}",
        b.stderr
    );
    assert!(
        std::panic::catch_unwind(|| check_no_remote(&b)).is_err(),
        "an injected remote image passed the check"
    );
}

#[test]
fn view_serve_answers_on_localhost_only() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("out");
    std::fs::create_dir(&out).unwrap();
    std::fs::write(out.join("index.html"), "<!DOCTYPE html><p>page</p>").unwrap();
    std::fs::create_dir(out.join("view")).unwrap();
    std::fs::write(out.join("view/x.js"), "PSV.tile('k','');").unwrap();
    let mut child = Command::new(BIN)
        .args([
            "view".as_ref(),
            out.as_os_str(),
            "--serve".as_ref(),
            "--no-write".as_ref(),
        ])
        .stdout(Stdio::piped())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    let mut line = String::new();
    BufReader::new(child.stdout.take().unwrap())
        .read_line(&mut line)
        .unwrap();
    let result = std::panic::catch_unwind(|| {
        let url = line.trim().rsplit(' ').next().unwrap().to_string();
        assert!(url.starts_with("http://127.0.0.1:"), "{line}");
        let addr: std::net::SocketAddr = url
            .trim_start_matches("http://")
            .trim_end_matches('/')
            .parse()
            .unwrap();
        assert!(addr.ip().is_loopback() && addr.port() != 0);
        let get = |path: &str| {
            let mut s =
                std::net::TcpStream::connect_timeout(&addr, Duration::from_secs(5)).unwrap();
            s.set_read_timeout(Some(Duration::from_secs(5))).unwrap();
            write!(s, "GET {path} HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n").unwrap();
            let mut r = Vec::new();
            s.take(1 << 20).read_to_end(&mut r).unwrap();
            String::from_utf8_lossy(&r).to_string()
        };
        let r = get("/");
        assert!(
            r.starts_with("HTTP/1.1 200") && r.contains("<p>page</p>"),
            "{r}"
        );
        assert!(get("/view/x.js").starts_with("HTTP/1.1 200"));
        assert!(get("/../etc/passwd").starts_with("HTTP/1.1 404"));
    });
    let _ = child.kill();
    let _ = child.wait();
    if let Err(e) = result {
        std::panic::resume_unwind(e);
    }
}

/// The RTI layer: a synthetic Blinn–Phong sphere (160 × 160) under a 30-light dome, `run --rti BASIS --view` for
/// PTM, HSH order 3 and RBF; a screenshot of the layer with the light set through the URL must
/// match the library's CPU relighting of the fit the folder holds
/// ([`photostereo::io::viewer::rti::relight_rti`]) within 2/255 (mean absolute difference per
/// channel over the object), plain and with the enhancement modes (diffuse gain on PTM,
/// unsharp-masked normals with a specular highlight on HSH). Then the gloss layer
/// ([`check_gloss_layer`]).
#[test]
fn rti_layer_in_the_browser_matches_the_cpu_relighting() {
    use photostereo::io::viewer::rti::{blur_normals, relight_rti, Enhancement, UNSHARP_SIGMA};
    let Some(_) = chromium() else { return };
    let t0 = Instant::now();
    let tmp = tempfile::tempdir().unwrap();
    let cap = tmp.path().join("sphere");
    photostereo(&[
        "synth".as_ref(),
        "sphere".as_ref(),
        "--rig".as_ref(),
        "dome-30".as_ref(),
        "--size".as_ref(),
        "160".as_ref(),
        "-o".as_ref(),
        cap.as_os_str(),
        "-q".as_ref(),
    ]);
    let cases: [(&str, [f32; 3], Enhancement, f32); 5] = [
        ("ptm", [0.5, 0.3, 0.81], Enhancement::default(), 0.0),
        (
            "ptm",
            [-0.4, 0.2, 0.89],
            Enhancement {
                diffuse_gain: 3.0,
                unsharp: 0.0,
            },
            0.0,
        ),
        ("hsh3", [-0.6, -0.3, 0.74], Enhancement::default(), 0.0),
        (
            "hsh3",
            [0.3, 0.6, 0.74],
            Enhancement {
                diffuse_gain: 1.0,
                unsharp: 2.0,
            },
            0.4,
        ),
        ("rbf", [0.2, -0.5, 0.84], Enhancement::default(), 0.0),
    ];
    let mut done: Vec<&str> = Vec::new();
    for (basis, light, e, specular) in cases {
        let out = tmp.path().join(format!("out-{basis}"));
        if !done.contains(&basis) {
            photostereo(&[
                "run".as_ref(),
                cap.as_os_str(),
                "--rti".as_ref(),
                basis.as_ref(),
                "--view".as_ref(),
                "-o".as_ref(),
                out.as_os_str(),
                "-q".as_ref(),
            ]);
            done.push(basis);
        }
        let f = photostereo::io::viewer::RunFolder::read(&out, None).unwrap();
        let layer = f.rti.as_ref().expect("run --rti wrote rti.json");
        assert_eq!(layer.basis.name(), basis);
        let albedo: Vec<[f32; 3]> = (0..f.width * f.height)
            .map(|i| {
                let c = f.albedo_channels;
                let a = &f.albedo[i * c..i * c + c];
                let v = if c >= 3 {
                    [a[0], a[1], a[2]]
                } else {
                    [a[0]; 3]
                };
                v.map(|x| if x.is_finite() { x.max(0.0) } else { 0.0 })
            })
            .collect();
        let blurred = blur_normals(f.width, f.height, &f.normals, UNSHARP_SIGMA);
        let p = RelightParams {
            light,
            specular,
            shininess: 30.0,
            white: albedo_white(&f.albedo, f.albedo_channels, &f.mask),
            ..Default::default()
        };
        let frag = format!(
            "plain=1&layer=rti&light={},{},{}&specular={}&shininess={}&dgain={}&unsharp={}",
            light[0], light[1], light[2], specular, p.shininess, e.diffuse_gain, e.unsharp
        );
        let shot = screenshot(
            tmp.path(),
            &out.join("index.html"),
            &frag,
            (f.width, f.height),
        );
        let want = relight_rti(layer, &f.normals, &blurred, &albedo, &p, &e);
        let d = mad(&shot, &want, &f.mask);
        eprintln!(
            "rti {basis} {e:?} specular {specular}: browser vs CPU, mean |Δ| (1/255): {d:.3?}"
        );
        for c in d {
            assert!(
                c <= 2.0,
                "rti {basis}: mean absolute difference {d:?} > 2/255"
            );
        }
        let inside = f.mask.iter().filter(|&&m| m).count();
        let lit = want
            .iter()
            .zip(&f.mask)
            .filter(|(s, &m)| m && s[0] > 20)
            .count();
        assert!(lit > inside / 4, "rti {basis}: the object is dark");
        // The enhancement changes the picture (it is not silently off).
        if e != Enhancement::default() || specular > 0.0 {
            let plain = relight_rti(
                layer,
                &f.normals,
                &blurred,
                &albedo,
                &RelightParams { specular: 0.0, ..p },
                &Enhancement::default(),
            );
            let moved = mad(&plain, &want, &f.mask);
            assert!(
                moved.iter().any(|&v| v > 2.0),
                "rti {basis}: enhancement changes the image by only {moved:?}"
            );
        }
    }
    check_gloss_layer(tmp.path(), &cap);
    eprintln!("rti browser test: {:.1} s", t0.elapsed().as_secs_f64());
}

/// The gloss layer of `run --reflectance lobe --view`: specular strength and roughness drawn
/// with the map colour scale over [0, the map's largest value inside the mask], grey where the
/// lobe was not fitted, against the output folder's arrays.
fn check_gloss_layer(tmp: &Path, cap: &Path) {
    let out = tmp.join("out-gloss");
    photostereo(&[
        "run".as_ref(),
        cap.as_os_str(),
        "--reflectance".as_ref(),
        "lobe".as_ref(),
        "--view".as_ref(),
        "-o".as_ref(),
        out.as_os_str(),
        "-q".as_ref(),
    ]);
    let f = photostereo::io::viewer::RunFolder::read(&out, None).unwrap();
    let (strength, roughness) = f.gloss.as_ref().expect("the lobe maps");
    for (name, map) in [("strength", strength), ("roughness", roughness)] {
        let top = map
            .iter()
            .zip(&f.mask)
            .filter(|(v, &m)| m && v.is_finite())
            .fold(0f32, |a, (v, _)| a.max(*v));
        let fitted = map
            .iter()
            .zip(&f.mask)
            .filter(|(v, &m)| m && v.is_finite() && **v >= 0.0)
            .count();
        let inside = f.mask.iter().filter(|&&m| m).count();
        eprintln!("gloss {name}: {fitted} of {inside} mask pixels fitted");
        assert!(
            top > 0.0 && fitted * 10 >= inside,
            "{name}: {fitted} of {inside} fitted"
        );
        let want: Vec<[u8; 3]> = map
            .iter()
            .map(|&v| {
                if v.is_finite() && v >= 0.0 {
                    colormap(v / top)
                } else {
                    [77; 3]
                }
            })
            .collect();
        let shot = screenshot(
            tmp,
            &out.join("index.html"),
            &format!("plain=1&layer=gloss&gloss={name}"),
            (f.width, f.height),
        );
        let d = mad(&shot, &want, &f.mask);
        eprintln!("gloss {name}: browser vs arrays, mean |Δ| (1/255): {d:.3?}");
        assert!(d.iter().all(|&c| c <= 2.0), "gloss {name}: {d:?}");
    }
}
