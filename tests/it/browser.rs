//! A real headless Chromium driven over the DevTools protocol (the small client in `cdp.rs`),
//! for tests of pages: open a URL, wait for a JavaScript condition, evaluate, click, press keys,
//! type, take a screenshot. A test takes the browser with `Browser::launch()`, which returns
//! `None` (and prints SKIPPED) when Chromium is absent; browser tests run one at a time (each
//! holds a process-wide lock) and each has its own Chromium, killed when the `Browser` drops.

use crate::cdp::{Chromium, Connection};
use crate::common::unbase64;
use serde_json::{json, Value};
use std::cell::RefCell;
use std::path::Path;
use std::sync::{Mutex, MutexGuard};
use std::time::{Duration, Instant};

pub const CHROMIUM: &str = "/usr/bin/chromium";
/// The viewport of every tab (CSS pixels at device scale 1, so screenshot pixels too).
pub const VIEWPORT: (u32, u32) = (1300, 1000);

/// Collects the page's uncaught errors and rejections in `window.__kfErrors`, installed before
/// any of the page's own scripts run.
const ERROR_COLLECTOR: &str = "window.__kfErrors = [];\
    window.addEventListener('error', function (e) { window.__kfErrors.push(String(e.message)); });\
    window.addEventListener('unhandledrejection', function (e) { window.__kfErrors.push('unhandled rejection: ' + String(e.reason)); });";

static ONE_AT_A_TIME: Mutex<()> = Mutex::new(());

/// One headless Chromium (killed on drop) and the lock that keeps browser tests serial.
pub struct Browser {
    chromium: RefCell<Chromium>,
    _turn: MutexGuard<'static, ()>,
}

/// One page of the browser.
pub struct Tab<'b> {
    id: String,
    page: RefCell<Connection>,
    browser: &'b Browser,
}

impl Browser {
    /// Starts Chromium headless without sandbox, or returns `None` after printing SKIPPED when
    /// `/usr/bin/chromium` is absent. Waits for any other browser test of this process first.
    /// Panics when Chromium is present but does not start.
    pub fn launch() -> Option<Browser> {
        if !Path::new(CHROMIUM).exists() {
            println!("SKIPPED: {CHROMIUM} is absent (install the Debian package chromium)");
            return None;
        }
        let turn = ONE_AT_A_TIME
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner);
        let t = Instant::now();
        let size = format!("--window-size={},{}", VIEWPORT.0, VIEWPORT.1);
        let args = [
            "--disable-quic",
            "--disable-component-update",
            "--hide-scrollbars",
            "--force-device-scale-factor=1",
            size.as_str(),
        ];
        let chromium = Chromium::start(CHROMIUM, &args).unwrap_or_else(|e| panic!("{e}"));
        eprintln!("chromium launched in {:?}", t.elapsed());
        Some(Browser {
            chromium: RefCell::new(chromium),
            _turn: turn,
        })
    }

    /// Opens `url` in a new tab of the viewport's size and waits until it has loaded.
    pub fn open(&self, url: &str) -> Tab<'_> {
        let (id, page) = self
            .chromium
            .borrow_mut()
            .new_page()
            .unwrap_or_else(|e| panic!("{e}"));
        let tab = Tab {
            id,
            page: RefCell::new(page),
            browser: self,
        };
        tab.call(
            "Emulation.setDeviceMetricsOverride",
            json!({"width": VIEWPORT.0, "height": VIEWPORT.1, "deviceScaleFactor": 1, "mobile": false}),
        );
        tab.call("Page.enable", json!({}));
        tab.call(
            "Page.addScriptToEvaluateOnNewDocument",
            json!({ "source": ERROR_COLLECTOR }),
        );
        let r = tab.call("Page.navigate", json!({ "url": url }));
        assert!(r.get("errorText").is_none(), "open {url}: {r}");
        tab.wait_for(
            "location.href !== 'about:blank' && document.readyState === 'complete'",
            Duration::from_secs(30),
        )
        .unwrap_or_else(|e| panic!("open {url}: {e}"));
        tab
    }
}

impl Tab<'_> {
    /// Sends one DevTools command to the page; panics on a protocol error.
    pub fn call(&self, method: &str, params: Value) -> Value {
        self.page
            .borrow_mut()
            .call(method, params)
            .unwrap_or_else(|e| panic!("{e}"))
    }

    /// Evaluates `expr` in the page (awaiting a promise) and returns its value as JSON, or the
    /// exception's description. `undefined` is `Value::Null`.
    pub fn try_eval(&self, expr: &str) -> Result<Value, String> {
        let params = json!({"expression": expr, "returnByValue": true, "awaitPromise": true, "userGesture": true});
        let r = self.page.borrow_mut().call("Runtime.evaluate", params)?;
        if let Some(ex) = r.get("exceptionDetails") {
            let what = ex["exception"]["description"]
                .as_str()
                .or(ex["text"].as_str())
                .unwrap_or("an exception");
            return Err(format!("{expr} threw: {what}"));
        }
        Ok(r["result"].get("value").cloned().unwrap_or(Value::Null))
    }

    /// `try_eval`, panicking on an exception.
    pub fn eval(&self, expr: &str) -> Value {
        self.try_eval(expr).unwrap_or_else(|e| panic!("{e}"))
    }

    /// Polls `condition` (a JavaScript expression) every 20 ms until it is truthy; on timeout the
    /// error names the condition and its last value or exception.
    pub fn wait_for(&self, condition: &str, timeout: Duration) -> Result<(), String> {
        let expr = format!("Boolean({condition})");
        let start = Instant::now();
        loop {
            let last = self.try_eval(&expr);
            if last == Ok(Value::Bool(true)) {
                return Ok(());
            }
            if start.elapsed() > timeout {
                return Err(format!(
                    "after {timeout:?}, {condition} is still {last:?}; page errors: {:?}",
                    self.errors()
                ));
            }
            std::thread::sleep(Duration::from_millis(20));
        }
    }

    /// The page's uncaught errors and unhandled rejections so far.
    pub fn errors(&self) -> Vec<String> {
        match self.try_eval("window.__kfErrors || []") {
            Ok(Value::Array(v)) => v
                .into_iter()
                .map(|e| e.as_str().unwrap_or_default().to_string())
                .collect(),
            other => vec![format!("no error collector: {other:?}")],
        }
    }

    fn mouse(&self, kind: &str, x: f64, y: f64) {
        let mut params = json!({"type": kind, "x": x, "y": y});
        if kind != "mouseMoved" {
            params["button"] = json!("left");
            params["clickCount"] = json!(1);
        }
        self.call("Input.dispatchMouseEvent", params);
    }

    /// Moves the mouse to (`x`, `y`) in viewport CSS pixels.
    pub fn hover(&self, x: f64, y: f64) {
        self.mouse("mouseMoved", x, y);
    }

    /// Moves the mouse to (`x`, `y`) and clicks the left button there.
    pub fn click(&self, x: f64, y: f64) {
        for kind in ["mouseMoved", "mousePressed", "mouseReleased"] {
            self.mouse(kind, x, y);
        }
    }

    /// Presses and releases a key by its DOM `key` name ("k", "Enter", "ArrowRight", "Escape",
    /// "Tab", "Backspace", "Delete", "Home", "End", "PageUp", "PageDown", " " or any single
    /// character), optionally after modifiers joined with '+': "Control+z", "Shift+ArrowLeft".
    pub fn key(&self, chord: &str) {
        let (mods, key) = match chord.rsplit_once('+') {
            Some((mods, key)) if !key.is_empty() => (mods, key),
            _ => ("", chord),
        };
        let modifiers = mods
            .split('+')
            .filter(|m| !m.is_empty())
            .map(|m| match m {
                "Alt" => 1,
                "Control" | "Ctrl" => 2,
                "Meta" => 4,
                "Shift" => 8,
                _ => panic!("unknown modifier {m:?} in {chord:?}"),
            })
            .fold(0, |a, b| a | b);
        let (code, vk, text) = key_codes(key).unwrap_or_else(|| panic!("unknown key {key:?}"));
        // Control, Alt and Meta chords type no text.
        let text = if modifiers & 7 == 0 { text } else { None };
        let mut down = json!({"type": if text.is_some() { "keyDown" } else { "rawKeyDown" },
            "key": key, "code": code, "windowsVirtualKeyCode": vk, "nativeVirtualKeyCode": vk,
            "modifiers": modifiers});
        if let Some(t) = text {
            down["text"] = json!(t);
            down["unmodifiedText"] = json!(t);
        }
        self.call("Input.dispatchKeyEvent", down);
        self.call(
            "Input.dispatchKeyEvent",
            json!({"type": "keyUp", "key": key, "code": code, "windowsVirtualKeyCode": vk,
                "nativeVirtualKeyCode": vk, "modifiers": modifiers}),
        );
    }

    /// Types `text` key by key (a keydown, input and keyup for each character) into the focused
    /// element.
    pub fn type_text(&self, text: &str) {
        let mut buf = [0u8; 4];
        for c in text.chars() {
            self.key(c.encode_utf8(&mut buf));
        }
    }

    /// A PNG of the viewport.
    pub fn screenshot_png(&self) -> Vec<u8> {
        let r = self.call("Page.captureScreenshot", json!({"format": "png"}));
        unbase64(r["data"].as_str().expect("screenshot data"))
    }
}

/// The DOM `code`, the Windows virtual key code and the typed text of a key.
fn key_codes(key: &str) -> Option<(String, u32, Option<String>)> {
    let named = |code: &str, vk: u32, text: Option<&str>| {
        Some((code.to_string(), vk, text.map(str::to_string)))
    };
    match key {
        "Enter" => named("Enter", 13, Some("\r")),
        "Tab" => named("Tab", 9, None),
        "Escape" => named("Escape", 27, None),
        "Backspace" => named("Backspace", 8, None),
        "Delete" => named("Delete", 46, None),
        " " => named("Space", 32, Some(" ")),
        "ArrowLeft" => named("ArrowLeft", 37, None),
        "ArrowUp" => named("ArrowUp", 38, None),
        "ArrowRight" => named("ArrowRight", 39, None),
        "ArrowDown" => named("ArrowDown", 40, None),
        "Home" => named("Home", 36, None),
        "End" => named("End", 35, None),
        "PageUp" => named("PageUp", 33, None),
        "PageDown" => named("PageDown", 34, None),
        _ => {
            let mut chars = key.chars();
            let c = chars.next()?;
            if chars.next().is_some() {
                return None;
            }
            let upper = c.to_ascii_uppercase();
            let (code, vk) = if c.is_ascii_alphabetic() {
                (format!("Key{upper}"), u32::from(upper))
            } else if c.is_ascii_digit() {
                (format!("Digit{c}"), u32::from(c))
            } else {
                (String::new(), 0)
            };
            Some((code, vk, Some(c.to_string())))
        }
    }
}

impl Drop for Tab<'_> {
    fn drop(&mut self) {
        let _ = self.browser.chromium.borrow_mut().close_page(&self.id);
    }
}

/// The harness itself on a page made here: evaluation, a thrown error, a click on a button, text
/// typed into the clicked input, keys with modifiers, the error collector and a screenshot.
#[test]
fn browser_harness_evaluates_clicks_types_and_presses_keys() {
    let Some(browser) = Browser::launch() else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let page = dir.path().join("harness.html");
    std::fs::write(
        &page,
        r#"<!DOCTYPE html><html><body style="margin:0;background:#fff">
<button id="b" style="position:absolute;left:100px;top:50px;width:200px;height:80px;background:#204080;color:#fff">click</button>
<input id="i" style="position:absolute;left:100px;top:200px;width:300px;height:30px">
<script>
window.clicks = 0; window.keys = [];
document.getElementById('b').addEventListener('click', function () { window.clicks += 1; });
document.addEventListener('keydown', function (e) {
  window.keys.push((e.ctrlKey ? 'Control+' : '') + (e.shiftKey ? 'Shift+' : '') + e.key);
});
setTimeout(function () { document.body.dataset.late = 'yes'; }, 200);
</script></body></html>"#,
    )
    .unwrap();
    let tab = browser.open(&format!("file://{}", page.display()));
    assert_eq!(tab.eval("1 + 2"), serde_json::json!(3));
    assert_eq!(
        tab.eval("Promise.resolve({a: [1, 'x']})"),
        serde_json::json!({"a": [1, "x"]})
    );
    assert_eq!(tab.eval("undefined"), Value::Null);
    let err = tab.try_eval("noSuchFunction()").unwrap_err();
    assert!(err.contains("noSuchFunction"), "{err}");
    assert_eq!(
        tab.eval("[innerWidth, innerHeight, devicePixelRatio]"),
        serde_json::json!([VIEWPORT.0, VIEWPORT.1, 1])
    );
    // A condition that becomes true later, and one that never does.
    let t = Instant::now();
    tab.wait_for(
        "document.body.dataset.late === 'yes'",
        Duration::from_secs(5),
    )
    .unwrap();
    let never = tab
        .wait_for("window.clicks > 5", Duration::from_millis(200))
        .unwrap_err();
    assert!(never.contains("window.clicks > 5"), "{never}");
    eprintln!("waits took {:?}", t.elapsed());

    tab.click(200.0, 90.0);
    tab.click(200.0, 90.0);
    tab.click(600.0, 600.0); // outside the button
    assert_eq!(tab.eval("window.clicks"), serde_json::json!(2));
    tab.click(150.0, 215.0);
    assert_eq!(tab.eval("document.activeElement.id"), "i");
    tab.type_text("Key 7");
    assert_eq!(tab.eval("document.getElementById('i').value"), "Key 7");
    tab.eval("window.keys = []");
    for chord in ["k", "Enter", "ArrowRight", "Shift+ArrowLeft", "Control+z"] {
        tab.key(chord);
    }
    assert_eq!(
        tab.eval("window.keys"),
        serde_json::json!(["k", "Enter", "ArrowRight", "Shift+ArrowLeft", "Control+z"])
    );
    assert_eq!(tab.errors(), Vec::<String>::new());
    tab.eval("setTimeout(function () { throw new Error('late failure'); }, 0)");
    tab.wait_for("window.__kfErrors.length > 0", Duration::from_secs(5))
        .unwrap();
    assert_eq!(tab.errors().len(), 1);
    assert!(
        tab.errors()[0].contains("late failure"),
        "{:?}",
        tab.errors()
    );

    // The screenshot: the viewport, white with the blue button where it was placed.
    let img = image::load_from_memory(&tab.screenshot_png())
        .unwrap()
        .to_rgb8();
    assert_eq!((img.width(), img.height()), VIEWPORT);
    assert_eq!(img.get_pixel(1000, 800).0, [255, 255, 255]);
    let [r, g, b] = img.get_pixel(110, 60).0;
    assert!(
        (i32::from(r) - 0x20).abs() <= 8
            && (i32::from(g) - 0x40).abs() <= 8
            && (i32::from(b) - 0x80).abs() <= 8,
        "button pixel {r},{g},{b}"
    );
}
