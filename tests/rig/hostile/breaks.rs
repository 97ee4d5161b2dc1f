//! The breaks a third hostile pass found (issue 44), each reproduced against the real binary
//! (loopback only, sentinels in the test's temp folder, no system file opened) and each failing
//! on a build without its fix (`RIG_BIN_UNDER_TEST=<older rig> cargo test --test rig
//! hostile::breaks::` runs them against another build).
//!
//! 1 manifest paths to devices and FIFOs; 2 `images/` swapped for a symlink during a fill;
//! 4 a Modbus timeout of 2^64 - 1 ms and a collection that ignored SIGINT and SIGTERM; 5 a
//! hard-linked `poses.csv`; 6 PNG bombs in ancillary chunks; 7 `rig eval --downstream` reading
//! what verify rejects; 8 two `Host` headers and absolute-form targets; 9 over-long paths and
//! serial ports that are not ports; and a grey control image for a package that reads one.

use std::os::unix::fs::symlink;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};

use rig::dataset::Source;
use rig::pose::Pose;

use super::*;

/// The sha256 the library sphere is recorded with (what a manifest naming it holds).
fn sphere_sha256() -> String {
    rig::geometry::objects::ObjectChoice::resolve("sphere", None).expect("the library sphere").sha256
}

/// [`dataset`], with the manifest's object naming `stl_path` (and the library sphere's hash).
fn dataset_naming_stl(dir: &Path, n: u32, stl_path: &str) {
    let object = ObjectInfo { name: "sphere".into(), stl_path: Some(stl_path.into()), stl_sha256: Some(sphere_sha256()) };
    let manifest = Manifest::new(SensorKind::TacTip, object, Some(PlanSpec::default()));
    let mut w = DatasetWriter::create(dir, manifest).expect("create");
    w.write_reference(&image(0)).expect("reference");
    for id in 0..n {
        let pose = PlanSpec::default().pose_of(id).expect("on grid");
        w.append(PoseRow::synthetic(id, pose, "m", 1, 2, 1.0), &image(id as u8 + 1)).expect("append");
    }
    w.finish().expect("finish");
}

fn rows(dir: &Path) -> usize {
    rig::dataset::read_rows(dir).expect("rows").len()
}

/// (Break 1.) A manifest's `stl_path` naming a FIFO, `/dev/null` or `/dev/zero` (with the hash
/// of the library object, which the fill and eval used to fall back to) is refused, exit 2,
/// "not a regular file", by the fill, a daemon synth job and `rig eval`, never opened (the
/// devices are only named) and never replaced by the library object.
#[test]
fn manifest_paths_to_devices_and_fifos_are_refused_without_a_fallback() {
    let sb = Sandbox::new();
    let w = sb.work();
    let fifo = sb.top.join("outside/part.stl");
    mkfifo(&fifo);
    copy_package(&w.join("pkg"));
    let named = [fifo.display().to_string(), "/dev/null".to_string(), "/dev/zero".to_string()];
    for (i, path) in named.iter().enumerate() {
        let ds = format!("ds{i}");
        dataset_naming_stl(&w.join(&ds), 1, path);
        let out = run_bounded(&w, &["synth", "--fill-missing", "--dataset", &ds, "--model", "pkg", "--steps", "1", "--limit", "1"]);
        let all = expect(&out, 2, "not a regular file");
        assert!(all.contains("stl_path"), "{all}");
        assert_eq!(rows(&w.join(&ds)), 1, "{path}: nothing may be filled from another object");
    }

    // The same dataset as a daemon job.
    let daemon = DaemonProcess::start(&w, &[], &[]);
    let id = daemon.submit(&serde_json::json!({"kind": "synth", "dataset": "ds2", "model": "pkg", "steps": 1, "limit": 1}));
    let job = daemon.wait_final(id);
    assert_eq!((job["state"].as_str(), job["exit_code"].as_u64()), (Some("failed"), Some(2)), "{job}");
    assert!(job["error"].as_str().is_some_and(|e| e.contains("not a regular file")), "{job}");
    drop(daemon);

    // rig eval: the real side's object names /dev/zero.
    let poses = [(1, Pose::new(0.0, 0.0, 0.0, 0.0)), (2, Pose::new(2.0, -1.0, 0.5, 30.0))];
    for (name, source) in [("real", Source::Real), ("syn", Source::Synthetic)] {
        let object = if source == Source::Real {
            ObjectInfo { name: "sphere".into(), stl_path: Some("/dev/zero".into()), stl_sha256: Some(sphere_sha256()) }
        } else {
            ObjectInfo::named("sphere")
        };
        let mut manifest = Manifest::new(SensorKind::TacTip, object, None);
        manifest.calibration = Some("default".into());
        let mut writer = DatasetWriter::create(&w.join(name), manifest).expect("create");
        writer.write_reference(&image(0)).expect("reference");
        for (id, pose) in poses {
            let row = match source {
                Source::Synthetic => PoseRow::synthetic(id, pose, "m", 0, 1, 1.0),
                other => PoseRow::commanded_only(id, pose, other),
            };
            writer.append(row, &image(id as u8)).expect("append");
        }
        writer.finish().expect("finish");
    }
    expect(&run_bounded(&w, &["eval", "--real", "real", "--synthetic", "syn"]), 2, "not a regular file");
    sb.assert_no_copy_of_the_secret();
}

/// (Break 2.) `images/` swapped for a symlink to a folder outside (atomically, `RENAME_EXCHANGE`,
/// in a loop) while `rig synth --fill-missing --limit 2` writes: nothing lands in the link's
/// target, and every row the fill appended has its image (the fill may also stop, exit 2,
/// having met the link: then the dataset is as consistent).
#[test]
fn a_fill_never_writes_through_an_images_folder_swapped_for_a_symlink() {
    let sb = Sandbox::new();
    let w = sb.work();
    let target = sb.top.join("outside/target");
    std::fs::create_dir(&target).expect("mkdir");
    copy_package(&w.join("pkg"));
    let mut filled = 0;
    for attempt in 0..8 {
        let ds = w.join(format!("ds{attempt}"));
        dataset(&ds, 1);
        symlink(&target, ds.join("images.link")).expect("symlink");
        let stop = Arc::new(AtomicBool::new(false));
        let swapper = {
            let (stop, ds) = (Arc::clone(&stop), ds.clone());
            std::thread::spawn(move || {
                let exchange = || {
                    rustix::fs::renameat_with(
                        rustix::fs::CWD,
                        ds.join("images"),
                        rustix::fs::CWD,
                        ds.join("images.link"),
                        rustix::fs::RenameFlags::EXCHANGE,
                    )
                    .expect("exchanging images/ and the link")
                };
                let mut swaps = 0u64;
                while !stop.load(Ordering::Relaxed) && swaps < 5_000_000 {
                    exchange();
                    swaps += 1;
                }
                // Leave images/ the folder again.
                if std::fs::symlink_metadata(ds.join("images")).expect("lstat").file_type().is_symlink() {
                    exchange();
                    swaps += 1;
                }
                swaps
            })
        };
        let ds_arg = ds.display().to_string();
        let out = run_bounded(&w, &["synth", "--fill-missing", "--dataset", &ds_arg, "--model", "pkg", "--steps", "1", "--limit", "2"]);
        stop.store(true, Ordering::Relaxed);
        let swaps = swapper.join().expect("swapper");
        assert!(swaps > 0, "the swapper never ran");
        let written: Vec<_> = std::fs::read_dir(&target).expect("ls").map(|e| e.expect("entry").file_name()).collect();
        assert!(written.is_empty(), "attempt {attempt}: written through the link: {written:?}\n{}", text(&out));
        std::fs::remove_file(ds.join("images.link")).expect("rm link");
        let report = rig::dataset::verify(&ds).expect("verify");
        assert_eq!(report.missing, 0, "attempt {attempt}: rows without their image:\n{report}\n{}", text(&out));
        match out.status.code() {
            Some(0) => {
                assert!(report.is_clean() && report.rows == 3, "attempt {attempt}:\n{report}");
                filled += 1;
            }
            Some(2) => assert!(text(&out).contains("symlink"), "attempt {attempt}: {}", text(&out)),
            other => panic!("attempt {attempt}: exit {other:?}: {}", text(&out)),
        }
    }
    eprintln!("{filled} of 8 fills ran to the end while images/ was swapped");
    sb.assert_no_copy_of_the_secret();
}

/// A loopback TCP server that accepts and never answers (a Modbus device gone silent);
/// `heard` turns true once a request's bytes arrived.
fn silent_server() -> (SocketAddr, Arc<AtomicBool>) {
    let listener = std::net::TcpListener::bind("127.0.0.1:0").expect("bind");
    let addr = listener.local_addr().expect("addr");
    let heard = Arc::new(AtomicBool::new(false));
    let flag = Arc::clone(&heard);
    std::thread::spawn(move || {
        for stream in listener.incoming().map_while(Result::ok) {
            let flag = Arc::clone(&flag);
            std::thread::spawn(move || {
                let mut stream = stream;
                let mut buf = [0u8; 256];
                while let Ok(n) = stream.read(&mut buf) {
                    if n == 0 {
                        break;
                    }
                    flag.store(true, Ordering::Relaxed);
                }
            });
        }
    });
    (addr, heard)
}

/// (Break 4.) A Modbus `timeout_ms` of 2^64 - 1 is refused (exit 2, naming its range); with the
/// largest valid one (60 s) and a device that never answers, SIGINT and SIGTERM each end a
/// collection within seconds, exit 4, the arm retracted and disabled (a failed disable would
/// be exit 3, a failed retract is logged), long before the 60 s timeout would have.
#[test]
fn a_collection_waiting_on_a_silent_device_ends_on_sigint_and_sigterm() {
    let sb = Sandbox::new();
    let w = sb.work();
    let (addr, heard) = silent_server();
    let config = |timeout_ms: &str| {
        format!(
            "[modbus.force]\ntransport = \"tcp\"\naddress = \"{addr}\"\ntimeout_ms = {timeout_ms}\n\
             read = [{{ name = \"force_N\", kind = \"input\", register = 0 }}]\n"
        )
    };
    std::fs::write(w.join("forever.toml"), config("18446744073709551615")).expect("write");
    std::fs::write(w.join("minute.toml"), config("60000")).expect("write");
    let all = expect(&run_bounded(&w, &["collect", "--config", "forever.toml", "--dry-run"]), 2, "timeout_ms");
    assert!(all.contains("1 to 60000 ms"), "{all}");

    for (signal, name) in [(libc::SIGINT, "SIGINT"), (libc::SIGTERM, "SIGTERM")] {
        heard.store(false, Ordering::Relaxed);
        let out = format!("out-{name}");
        let child = rig(&w)
            .args(["collect", "--config", "minute.toml", "--sensor", "tactip", "--poses", "2", "--out", &out])
            .env("RIG_LOG", "warn")
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .expect("spawn");
        let t0 = Instant::now();
        while !heard.load(Ordering::Relaxed) {
            assert!(t0.elapsed() < Duration::from_secs(60), "{name}: the collection never asked the device");
            std::thread::sleep(Duration::from_millis(20));
        }
        let pid = i32::try_from(child.id()).expect("pid");
        let sent = Instant::now();
        // SAFETY: kill(2) on our own child's pid, with a valid signal number.
        assert_eq!(unsafe { libc::kill(pid, signal) }, 0, "sending {name}");
        // Generous: the documented deadline is 5 s; the device's timeout is 60 s.
        let output = wait_or_kill(child, Duration::from_secs(30));
        let all = text(&output);
        assert_eq!(output.status.code(), Some(4), "{name} after {:?}:\n{all}", sent.elapsed());
        assert!(all.contains("interrupted"), "{name}: {all}");
        assert!(!all.contains("could not retract") && !all.contains("could not disable"), "{name}: {all}");
        let dataset = w.join(&out).join("sphere/tactip");
        assert!(rig::dataset::verify(&dataset).expect("verify").is_clean(), "{name}: the dataset must resume as it is");
    }
}

/// (Break 5.) A `poses.csv` that is a hard link to a file outside is refused when a fill opens it
/// for appending (exit 2, naming the link), and the file outside does not grow.
#[test]
fn a_hard_linked_poses_csv_is_not_appended_through() {
    let sb = Sandbox::new();
    let w = sb.work();
    copy_package(&w.join("pkg"));
    dataset(&w.join("ds"), 1);
    let outside = sb.top.join("outside/poses.csv");
    std::fs::rename(w.join("ds/poses.csv"), &outside).expect("mv");
    std::fs::hard_link(&outside, w.join("ds/poses.csv")).expect("hard link");
    let before = std::fs::read(&outside).expect("read");
    let out = run_bounded(&w, &["synth", "--fill-missing", "--dataset", "ds", "--model", "pkg", "--steps", "1", "--limit", "1"]);
    let all = expect(&out, 2, "hard link");
    assert!(all.contains("poses.csv"), "{all}");
    assert_eq!(std::fs::read(&outside).expect("read"), before, "the file outside the dataset changed");
}

/// A PNG chunk: length, type, data, CRC.
fn png_chunk(kind: &[u8; 4], data: &[u8]) -> Vec<u8> {
    let mut out = (data.len() as u32).to_be_bytes().to_vec();
    out.extend_from_slice(kind);
    out.extend_from_slice(data);
    let crc = crc32(&out[4..]);
    out.extend_from_slice(&crc.to_be_bytes());
    out
}

/// `png` (a whole PNG file) with `extra` inserted after its IHDR chunk (before the pixels).
fn png_with(png: &[u8], extra: &[u8]) -> Vec<u8> {
    // Signature (8) + IHDR (4 + 4 + 13 + 4).
    let mut out = png[..33].to_vec();
    out.extend_from_slice(extra);
    out.extend_from_slice(&png[33..]);
    out
}

/// A zlib stream of `1 + 258 * matches` zero bytes in one fixed-Huffman deflate block: a
/// literal 0, then `matches` copies of length 258 at distance 1 (13 bits each).
fn zlib_zeros(matches: u64) -> Vec<u8> {
    struct Bits {
        out: Vec<u8>,
        acc: u64,
        n: u32,
    }
    impl Bits {
        /// `len` bits of `value`, least significant first.
        fn put(&mut self, value: u64, len: u32) {
            self.acc |= value << self.n;
            self.n += len;
            while self.n >= 8 {
                self.out.push(self.acc as u8);
                self.acc >>= 8;
                self.n -= 8;
            }
        }
        /// A Huffman code: most significant bit first.
        fn code(&mut self, code: u64, len: u32) {
            let reversed = (0..len).fold(0, |r, i| r | (((code >> i) & 1) << (len - 1 - i)));
            self.put(reversed, len);
        }
    }
    let mut bits = Bits { out: vec![0x78, 0x01], acc: 0, n: 0 };
    bits.put(1, 1); // BFINAL
    bits.put(1, 2); // BTYPE = 01, fixed Huffman
    bits.code(0x30, 8); // literal 0
    for _ in 0..matches {
        bits.code(0xC5, 8); // length 258 (symbol 285)
        bits.code(0, 5); // distance 1
    }
    bits.code(0, 7); // end of block (256)
    if bits.n > 0 {
        bits.put(0, 8 - bits.n);
    }
    let total = 1 + 258 * matches;
    let adler = ((total % 65521) << 16) | 1;
    let mut out = bits.out;
    out.extend_from_slice(&(adler as u32).to_be_bytes());
    out
}

/// (Break 6.) Ancillary chunks are bounded: an image whose `iCCP` colour profile inflates to
/// 400 MB (a 2.5 MB file) and one with three million `tEXt` chunks (42 MB) verify clean with
/// the process's data memory (RLIMIT_DATA: heap and anonymous mappings) limited to 256 MiB;
/// before, the profile was inflated (400 MB) and each text chunk kept (290 MB), and the
/// allocation past the limit aborted rig.
#[test]
fn png_bombs_in_ancillary_chunks_cost_no_memory() {
    let sb = Sandbox::new();
    let w = sb.work();
    let mut plain = Vec::new();
    image(1).write_to(&mut std::io::Cursor::new(&mut plain), image::ImageFormat::Png).expect("encode");
    let mut profile = b"bomb\0\0".to_vec();
    profile.extend(zlib_zeros(400_000_000 / 258));
    let iccp = png_with(&plain, &png_chunk(b"iCCP", &profile));
    let one = png_chunk(b"tEXt", b"k\0");
    let texts = one.repeat(3_000_000);
    let text_bomb = png_with(&plain, &texts);
    drop(texts);
    for (name, bomb) in [("iCCP", iccp), ("tEXt", text_bomb)] {
        let ds = w.join(format!("ds-{name}"));
        dataset(&ds, 1);
        std::fs::write(ds.join("images/0.png"), &bomb).expect("write");
        drop(bomb);
        let ds = ds.display().to_string();
        let out = run_with_limit(&w, &["dataset", "verify", &ds], libc::RLIMIT_DATA, 256 << 20);
        let all = expect(&out, 0, "clean");
        assert!(!all.contains("NOT clean"), "{name}: {all}");
    }
}

/// A dataset of `n` captured rows at distinct poses, 8 x 8 px images (one of `odd_size` when
/// given: pose 3's).
fn captured_dataset(dir: &Path, n: u32, odd_size: Option<u32>) {
    let manifest = Manifest::new(SensorKind::TacTip, ObjectInfo::named("sphere"), None);
    let mut w = DatasetWriter::create(dir, manifest).expect("create");
    w.write_reference(&image(0)).expect("reference");
    for id in 0..n {
        let pose = Pose::new(f64::from(id % 5) - 2.0, 0.0, f64::from(id / 5) * 0.25, f64::from(id % 3) * 15.0);
        let img = match odd_size {
            Some(side) if id == 3 => image::RgbImage::from_pixel(side, side, image::Rgb([9, 9, 9])),
            _ => image::RgbImage::from_fn(8, 8, |x, y| image::Rgb([(x * 20 + id) as u8, (y * 20) as u8, (id * 7) as u8])),
        };
        w.append(PoseRow::commanded_only(id, pose, Source::Simulated), &img).expect("append");
    }
    w.finish().expect("finish");
}

/// (Break 7.) `rig eval --downstream` reads by verify's rules: an image of another size than
/// its dataset's (1 x 1 among 8 x 8), a `z_mm = 1e308` (refused as bad input, not trained on
/// until it diverges) and two copies of one dataset (a test row's twin would train) are each
/// exit 2 naming what is wrong; the clean folder trains.
#[test]
fn downstream_refuses_what_verify_rejects_and_copies_of_one_dataset() {
    let sb = Sandbox::new();
    let w = sb.work();
    let eval =
        |dir: &str| run_bounded(&w, &["eval", "--downstream", dir, "--sets", "real", "--seeds", "1", "--epochs", "1", "--size", "16"]);
    captured_dataset(&w.join("clean/a"), 25, None);
    expect(&eval("clean"), 0, "");

    captured_dataset(&w.join("sizes/a"), 25, Some(1));
    expect(&eval("sizes"), 2, "the dataset's images are 8x8 px");
    assert!(!rig::dataset::verify(&w.join("sizes/a")).expect("verify").is_clean(), "verify reports it too");

    captured_dataset(&w.join("huge/a"), 25, None);
    let csv = std::fs::read_to_string(w.join("huge/a/poses.csv")).expect("csv");
    let mut lines: Vec<String> = csv.lines().map(String::from).collect();
    let mut fields: Vec<String> = lines[4].split(',').map(String::from).collect();
    fields[3] = "1e308".into();
    lines[4] = fields.join(",");
    std::fs::write(w.join("huge/a/poses.csv"), lines.join("\n") + "\n").expect("write");
    expect(&eval("huge"), 2, "z_mm = 1e308");
    assert!(!rig::dataset::verify(&w.join("huge/a")).expect("verify").is_clean(), "verify reports it too");

    captured_dataset(&w.join("copies/a"), 25, None);
    std::fs::create_dir(w.join("copies/b")).expect("mkdir");
    for f in ["manifest.toml", "poses.csv", "reference.png"] {
        std::fs::copy(w.join("copies/a").join(f), w.join("copies/b").join(f)).expect("cp");
    }
    std::fs::create_dir(w.join("copies/b/images")).expect("mkdir");
    for e in std::fs::read_dir(w.join("copies/a/images")).expect("ls") {
        let e = e.expect("entry");
        std::fs::copy(e.path(), w.join("copies/b/images").join(e.file_name())).expect("cp");
    }
    expect(&eval("copies"), 2, "same dataset");
}

/// (Break 8.) Exactly one `Host`, and a target that is a path: a request with two `Host` headers
/// (either order) or an absolute-form target (naming another host or the daemon itself) is a
/// JSON 400; the plain request is answered.
#[test]
fn two_host_headers_and_absolute_targets_are_refused() {
    let sb = Sandbox::new();
    let daemon = DaemonProcess::start(&sb.work(), &[], &[]);
    let addr = daemon.addr;
    for (what, request) in [
        ("two Host headers", format!("GET /api/status HTTP/1.1\r\nHost: {addr}\r\nHost: evil.com\r\nConnection: close\r\n\r\n")),
        (
            "two Host headers, foreign first",
            format!("GET /api/status HTTP/1.1\r\nHost: evil.com\r\nHost: {addr}\r\nConnection: close\r\n\r\n"),
        ),
        ("an absolute-form target", format!("GET http://evil.com/api/status HTTP/1.1\r\nHost: {addr}\r\nConnection: close\r\n\r\n")),
        (
            "an absolute-form target naming the daemon",
            format!("GET http://{addr}/api/status HTTP/1.1\r\nHost: {addr}\r\nConnection: close\r\n\r\n"),
        ),
    ] {
        let r = daemon.send(&request);
        assert_eq!(r.status, 400, "{what}: {}", String::from_utf8_lossy(&r.body));
        let e = error_of(&r);
        assert!(e.contains("Host") || e.contains("absolute URL"), "{what}: {e}");
    }
    assert_eq!(daemon.request("GET", "/api/status", "", "").status, 200);
}

/// (Break 9.) Bad input is exit 2 (or 400) when it is met, not a failure later: a job `out` of
/// 30 components of 255 bytes is refused at submission (before, it was queued and failed with
/// exit 1), and so is the same `--out` on the command line; an arm `serial_port` that is a
/// regular file, a FIFO or `/dev/null` (only named) is refused without being opened (before:
/// exit 3, "Not a typewriter").
#[test]
fn long_paths_and_serial_ports_that_are_not_ports_are_bad_input() {
    let sb = Sandbox::new();
    let w = sb.work();
    let long = vec!["d".repeat(255); 30].join("/");
    let daemon = DaemonProcess::start(&w, &[], &[]);
    let before = daemon.job_count();
    let body = serde_json::json!({"kind": "collect", "object": "sphere", "sensor": "tactip", "poses": 1, "out": long}).to_string();
    let r = daemon.request("POST", "/api/jobs", "Content-Type: application/json\r\nX-Rig-Client: test\r\n", &body);
    assert_eq!(r.status, 400, "{}", String::from_utf8_lossy(&r.body));
    let e = error_of(&r);
    assert!(e.contains("out") && e.contains("bytes a component"), "{e}");
    assert_eq!(daemon.job_count(), before, "nothing was queued");
    drop(daemon);
    expect(&run_bounded(&w, &["collect", "--sensor", "tactip", "--poses", "1", "--out", &long]), 2, "bytes a component");

    std::fs::write(w.join("not-a-port"), b"").expect("write");
    mkfifo(&w.join("fifo-port"));
    for (port, found) in [("not-a-port", "a regular file"), ("fifo-port", "a FIFO"), ("/dev/null", "memory device")] {
        let config = format!("port-{}.toml", found.replace(' ', "-"));
        std::fs::write(w.join(&config), format!("[arm]\nbackend = \"magician\"\nserial_port = \"{port}\"\n")).expect("write");
        let out = run_bounded(&w, &["collect", "--config", &config, "--sensor", "tactip", "--poses", "1", "--out", "m"]);
        let all = expect(&out, 2, "is not a serial port");
        assert!(all.contains(found), "{all}");
    }
    assert!(!w.join("m").exists(), "nothing was collected");
}

/// (The grey control.) A package that declares no control colour map (as diffusers' depth and
/// edge ControlNets are exported) reads a grey control image; rig's own packages
/// (`control_colour_map = "viridis"`) still refuse it.
#[test]
fn a_grey_control_image_is_read_unless_the_package_declares_a_colour_map() {
    let sb = Sandbox::new();
    let w = sb.work();
    copy_package(&w.join("viridis"));
    let undeclared = copy_package(&w.join("plain"));
    let toml = std::fs::read_to_string(undeclared.join("model.toml")).expect("model.toml");
    assert!(toml.contains("control_colour_map = \"viridis\""), "the tiny package declares its colour map");
    let plain: String = toml.lines().filter(|l| !l.starts_with("control_colour_map")).map(|l| format!("{l}\n")).collect();
    std::fs::write(undeclared.join("model.toml"), plain).expect("write");
    image::RgbImage::from_fn(64, 64, |x, y| {
        let v = ((x + y) * 2) as u8;
        image::Rgb([v, v, v])
    })
    .save(w.join("grey.png"))
    .expect("png");
    let one = |model: &str, out: &str| {
        run_bounded(&w, &["synth", "one", "--model", model, "--control", "grey.png", "--prompt", "p", "--steps", "1", "--out", out])
    };
    expect(&one("plain", "plain.png"), 0, "");
    let made = image::open(w.join("plain.png")).expect("the synthesised image");
    assert_eq!((made.width(), made.height()), (64, 64));
    expect(&one("viridis", "viridis.png"), 2, "every pixel is grey");
    assert!(!w.join("viridis.png").exists());
}
