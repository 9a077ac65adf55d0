//! A real headless Chromium driven over the DevTools protocol (the `headless_chrome` crate, sync),
//! for tests of pages: open a URL, wait for a JavaScript condition, evaluate, click, press keys,
//! type, take a screenshot. A test takes the browser with `Browser::launch()`, which returns
//! `None` (and prints SKIPPED) when Chromium is absent; browser tests run one at a time (each
//! holds a process-wide lock) and each has its own Chromium, killed when the `Browser` drops.

use headless_chrome::browser::tab::ModifierKey;
use headless_chrome::protocol::cdp::{Emulation, Page, Runtime};
use headless_chrome::LaunchOptions;
use serde_json::Value;
use std::ffi::OsStr;
use std::path::Path;
use std::sync::{Arc, Mutex, MutexGuard};
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
    inner: headless_chrome::Browser,
    _turn: MutexGuard<'static, ()>,
}

/// One page of the browser.
pub struct Tab<'b> {
    tab: Arc<headless_chrome::Tab>,
    _browser: &'b Browser,
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
        let args: Vec<&OsStr> = [
            "--disable-quic",
            "--disable-component-update",
            "--hide-scrollbars",
            "--force-device-scale-factor=1",
        ]
        .iter()
        .map(OsStr::new)
        .collect();
        let options = LaunchOptions {
            path: Some(CHROMIUM.into()),
            headless: true,
            sandbox: false,
            window_size: Some(VIEWPORT),
            args,
            idle_browser_timeout: Duration::from_secs(120),
            ..LaunchOptions::default()
        };
        let t = Instant::now();
        let inner = headless_chrome::Browser::new(options).expect("start headless Chromium");
        eprintln!("chromium launched in {:?}", t.elapsed());
        Some(Browser { inner, _turn: turn })
    }

    /// Opens `url` in a new tab of the viewport's size and waits until it has loaded.
    pub fn open(&self, url: &str) -> Tab<'_> {
        let tab = self.inner.new_tab().expect("new tab");
        tab.call_method(Emulation::SetDeviceMetricsOverride {
            width: VIEWPORT.0,
            height: VIEWPORT.1,
            device_scale_factor: 1.0,
            mobile: false,
            scale: None,
            screen_width: None,
            screen_height: None,
            position_x: None,
            position_y: None,
            dont_set_visible_size: None,
            screen_orientation: None,
            viewport: None,
            display_feature: None,
            device_posture: None,
        })
        .expect("set the viewport");
        tab.call_method(Page::AddScriptToEvaluateOnNewDocument {
            source: ERROR_COLLECTOR.to_string(),
            world_name: None,
            include_command_line_api: None,
            run_immediately: None,
        })
        .expect("install the error collector");
        tab.navigate_to(url)
            .and_then(|t| t.wait_until_navigated())
            .unwrap_or_else(|e| panic!("open {url}: {e}"));
        Tab {
            tab,
            _browser: self,
        }
    }
}

impl Tab<'_> {
    /// Evaluates `expr` in the page (awaiting a promise) and returns its value as JSON, or the
    /// exception's description. `undefined` is `Value::Null`.
    pub fn try_eval(&self, expr: &str) -> Result<Value, String> {
        let r = self
            .tab
            .call_method(Runtime::Evaluate {
                expression: expr.to_string(),
                return_by_value: Some(true),
                await_promise: Some(true),
                user_gesture: Some(true),
                object_group: None,
                include_command_line_api: None,
                silent: None,
                context_id: None,
                generate_preview: None,
                throw_on_side_effect: None,
                timeout: None,
                disable_breaks: None,
                repl_mode: None,
                allow_unsafe_eval_blocked_by_csp: None,
                unique_context_id: None,
                serialization_options: None,
            })
            .map_err(|e| format!("evaluate {expr}: {e}"))?;
        if let Some(ex) = r.exception_details {
            let what = ex.exception.and_then(|o| o.description).unwrap_or(ex.text);
            return Err(format!("{expr} threw: {what}"));
        }
        Ok(r.result.value.unwrap_or(Value::Null))
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

    /// Moves the mouse to (`x`, `y`) in viewport CSS pixels.
    pub fn hover(&self, x: f64, y: f64) {
        self.tab
            .move_mouse_to_point(headless_chrome::browser::tab::point::Point { x, y })
            .expect("move the mouse");
    }

    /// Moves the mouse to (`x`, `y`) and clicks the left button there.
    pub fn click(&self, x: f64, y: f64) {
        self.tab
            .click_point(headless_chrome::browser::tab::point::Point { x, y })
            .expect("click");
    }

    /// Presses and releases a key by its DOM `key` name ("k", "Enter", "ArrowRight", "Escape"),
    /// optionally after modifiers joined with '+': "Control+z", "Shift+ArrowLeft", "Alt+Meta+s".
    pub fn key(&self, chord: &str) {
        let (mods, key) = match chord.rsplit_once('+') {
            Some((mods, key)) if !key.is_empty() => (mods, key),
            _ => ("", chord),
        };
        let modifiers: Vec<ModifierKey> = mods
            .split('+')
            .filter(|m| !m.is_empty())
            .map(|m| match m {
                "Alt" => ModifierKey::Alt,
                "Control" | "Ctrl" => ModifierKey::Ctrl,
                "Meta" => ModifierKey::Meta,
                "Shift" => ModifierKey::Shift,
                _ => panic!("unknown modifier {m:?} in {chord:?}"),
            })
            .collect();
        let modifiers = (!modifiers.is_empty()).then_some(modifiers.as_slice());
        self.tab
            .press_key_with_modifiers(key, modifiers)
            .unwrap_or_else(|e| panic!("press {chord}: {e}"));
    }

    /// Types `text` key by key into the focused element.
    pub fn type_text(&self, text: &str) {
        self.tab
            .type_str(text)
            .unwrap_or_else(|e| panic!("type {text:?}: {e}"));
    }

    /// A PNG of the viewport.
    pub fn screenshot_png(&self) -> Vec<u8> {
        self.tab
            .capture_screenshot(Page::CaptureScreenshotFormatOption::Png, None, None, true)
            .expect("screenshot")
    }
}

impl Drop for Tab<'_> {
    fn drop(&mut self) {
        let _ = self.tab.close(false);
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
