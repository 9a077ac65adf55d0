//! Names near the file systems' 255-byte limit (issue 29): keyframer's temporaries stay within it
//! (a 250-byte image exports, a 245-byte project is written), and a name keyframer derives past it
//! (the checkpoint `P.partial`, the report's timeline) is refused before any work, naming it.

use crate::common::*;

#[test]
fn a_folder_holding_a_250_byte_image_name_exports() {
    let d = tempfile::tempdir().unwrap();
    let imgs = d.path().join("imgs");
    std::fs::create_dir(&imgs).unwrap();
    let long = format!("{}.png", "a".repeat(246));
    assert_eq!(long.len(), 250);
    for (i, name) in ["b0.png", long.as_str(), "c2.png"].iter().enumerate() {
        image::RgbImage::from_fn(32, 24, |x, y| {
            image::Rgb([x as u8 * 5, y as u8 * 7, i as u8 * 80])
        })
        .save(imgs.join(name))
        .unwrap();
    }
    let project = d.path().join("p.json");
    let sel = ["select", s(&imgs), "--every", "1", "--backend", "opencv"];
    kf_ok(&[&sel[..], &["-o", s(&project)]].concat());
    let out = d.path().join("E");
    kf_ok(&["export", s(&project), "--out", s(&out)]);
    let exported = out.join("images").join(&long);
    assert_eq!(
        std::fs::read(&exported).unwrap(),
        std::fs::read(imgs.join(&long)).unwrap()
    );
    assert_eq!(listing(&out.join("images")).len(), 3);
    // Again with --force (temporaries and staging once more), re-encoded.
    kf_ok(&[
        "export",
        s(&project),
        "--out",
        s(&out),
        "--force",
        "--resize",
        "16x12",
    ]);
    assert!(exported.is_file());
    assert_eq!(
        listing(&out),
        ["images", "manifest.json"],
        "no temporary left"
    );
}

#[test]
fn a_245_byte_project_name_is_written_and_longer_derived_names_are_refused_first() {
    let d = tempfile::tempdir().unwrap();
    let clip = testsrc(d.path(), "v.mp4", 64, 48, "10", 1.0);
    let sel = ["select", s(&clip), "--every", "3", "--backend", "opencv"];
    let name = format!("{}.json", "p".repeat(240));
    assert_eq!(name.len(), 245);
    let project = d.path().join(&name);
    kf_ok(&[&sel[..], &["-o", s(&project)]].concat());
    assert_eq!(keyframes(&project), [0, 3, 6, 9]);
    kf_ok(&[&sel[..], &["-o", s(&project), "--force"]].concat());
    // Its report: the page (240 bytes) and its `<stem>.timeline.png` (248) both fit.
    let html = d.path().join(format!("{}.html", "r".repeat(235)));
    kf_ok(&["report", s(&project), "-o", s(&html), "--thumbs", "0"]);
    assert!(html.is_file());
    // 250 bytes: the checkpoint beside it (`P.partial`) would have 258; said before decoding.
    let p250 = d.path().join(format!("{}.json", "q".repeat(245)));
    let (code, err) = code_and_stderr(&kf(&[&sel[..], &["-o", s(&p250)]].concat()));
    assert_eq!(code, 1, "{err}");
    assert!(
        err.contains(".json.partial") && err.contains("258 bytes"),
        "{err}"
    );
    // A 250-byte page: its timeline would have 258.
    let h250 = d.path().join(format!("{}.html", "h".repeat(245)));
    let (code, err) = code_and_stderr(&kf(&["report", s(&project), "-o", s(&h250)]));
    assert_eq!(code, 1, "{err}");
    assert!(
        err.contains(".timeline.png") && err.contains("258 bytes"),
        "{err}"
    );
    let mut left = listing(d.path());
    left.retain(|n| n != "v.mp4" && n != &name);
    assert_eq!(
        left.len(),
        2,
        "only the first page and its timeline: {left:?}"
    );
}

#[test]
fn a_long_input_name_gets_a_run_folder_within_the_limit() {
    let d = tempfile::tempdir().unwrap();
    let name = format!("{}.mp4", "v".repeat(246));
    let clip = testsrc(d.path(), &name, 64, 48, "10", 1.0);
    let w = d.path().join("w.toml");
    let text = "version = 1\n\n[analysis]\nbackend = \"opencv\"\n\n[[sample]]\nplugin = \"every-nth\"\nn = 5\n";
    std::fs::write(&w, text).unwrap();
    let out = d.path().join("runs");
    kf_ok(&["run", s(&w), s(&clip), "--out", s(&out)]);
    let folders = listing(&out);
    assert_eq!(folders, [keyframer::batch::folder_name(&clip)]);
    assert!(folders[0].len() <= 255, "{}", folders[0].len());
    assert!(out.join(&folders[0]).join("done.json").is_file());
}
