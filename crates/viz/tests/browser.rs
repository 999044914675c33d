//! The viewer in a real browser: pages built from realistic synthetic runs (a four-joint
//! chain following a flower-like target path, a 21 x 21 cloth falling onto a sphere
//! with a moving capsule and the ground, a stick figure's full-body clip) are opened in headless Chromium, driven from
//! outside over the Chrome DevTools Protocol, and checked:
//!
//! - no console error, no uncaught exception, no log entry of level error, nothing
//!   fetched;
//! - the 3D canvas is not blank;
//! - moving the timeline slider (setting its value and dispatching its input event)
//!   changes the picture, and so does dragging on the view (orbit);
//! - a click on a chart jumps to that frame, and play advances the frames;
//! - the decimation note is on the page, and the index links to every page.
//!
//! The browser is the program named by the `SINEW_CHROMIUM` environment variable, else
//! `/usr/bin/chromium` (the Debian package), else `chromium` on the PATH. There is no silent skip: when the browser
//! cannot start, the test fails with that message. Every page check runs under a time
//! limit, and the browser's whole process group is killed on every exit path.

use serde_json::{Value, json};
use sinew_math::DVec3;
use sinew_viz::viewer::{
    Budget, Collider, Frame, PageKind, PageSummary, Series, ViewerPage, write_page,
    write_scene_index,
};
use std::io::ErrorKind;
use std::net::TcpStream;
use std::os::unix::process::CommandExt;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::Mutex;
use std::time::{Duration, Instant};
use tungstenite::{Message, WebSocket};

/// The longest one page check may take (loading, drawing, every interaction).
const PAGE_TIME_LIMIT: Duration = Duration::from_secs(90);
/// The longest the browser may take to start and accept the protocol connection.
const START_TIME_LIMIT: Duration = Duration::from_secs(60);

/// One browser at a time: the machine running the tests has few cores.
static BROWSER_LOCK: Mutex<()> = Mutex::new(());

// ---------------------------------------------------------------------------------
// The browser and its DevTools protocol connection.
// ---------------------------------------------------------------------------------

/// A headless Chromium started for one test, with a websocket to its browser target.
/// Dropping it kills the browser's process group and removes its profile directory.
struct Browser {
    child: Child,
    workdir: PathBuf,
    socket: Option<WebSocket<TcpStream>>,
    next_id: u64,
    /// Protocol events received so far (exceptions, console calls, log entries).
    events: Vec<Value>,
}

impl Drop for Browser {
    fn drop(&mut self) {
        if let Some(mut socket) = self.socket.take() {
            let _ = socket.close(None);
        }
        // The browser was started as the leader of its own process group, so its
        // renderer and GPU helper processes go with it.
        let _ = Command::new("kill")
            .args(["-KILL", "--", &format!("-{}", self.child.id())])
            .stderr(Stdio::null())
            .status();
        let _ = self.child.kill();
        let _ = self.child.wait();
        let _ = std::fs::remove_dir_all(&self.workdir);
    }
}

impl Browser {
    /// Starts headless Chromium (`SINEW_CHROMIUM` or `/usr/bin/chromium`) with a fresh
    /// profile and connects to it.
    fn start(name: &str) -> Result<Browser, String> {
        let program = std::env::var("SINEW_CHROMIUM").unwrap_or_else(|_| {
            // The Debian package's path, else whatever `chromium` the PATH finds.
            if Path::new("/usr/bin/chromium").exists() {
                "/usr/bin/chromium".into()
            } else {
                "chromium".into()
            }
        });
        Browser::start_program(&program, name)
    }

    /// Starts the browser `program` with a fresh profile and connects to it.
    fn start_program(program: &str, name: &str) -> Result<Browser, String> {
        let workdir = PathBuf::from(env!("CARGO_TARGET_TMPDIR"))
            .join(format!("chromium-{name}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&workdir);
        let profile = workdir.join("profile");
        std::fs::create_dir_all(&profile)
            .map_err(|e| format!("cannot create {}: {e}", profile.display()))?;
        let log_path = workdir.join("chromium.log");
        let log = std::fs::File::create(&log_path)
            .map_err(|e| format!("cannot create {}: {e}", log_path.display()))?;
        // The flags keep a closed network quiet (no background connections, updates,
        // sync or QUIC) and make the browser work without a GPU, display or sandbox.
        let child = Command::new(program)
            .args([
                "--headless",
                "--no-sandbox",
                "--disable-gpu",
                "--disable-quic",
                "--no-first-run",
                "--no-default-browser-check",
                "--disable-background-networking",
                "--disable-component-update",
                "--disable-sync",
                "--disable-dev-shm-usage",
                "--remote-debugging-address=127.0.0.1",
                "--remote-debugging-port=0",
                "--window-size=1280,900",
                "--hide-scrollbars",
            ])
            .arg(format!("--user-data-dir={}", profile.display()))
            .arg("about:blank")
            .stdin(Stdio::null())
            .stdout(Stdio::null())
            .stderr(log)
            .process_group(0)
            .spawn()
            .map_err(|e| {
                // No browser, so no guard yet: clean up here.
                let _ = std::fs::remove_dir_all(&workdir);
                format!(
                    "cannot start the browser {program}: {e} (install the Debian package: apt-get install -y chromium)"
                )
            })?;
        let mut browser = Browser {
            child,
            workdir,
            socket: None,
            next_id: 0,
            events: Vec::new(),
        };
        // Chromium writes the port it chose and the browser target's path to this file
        // once it listens.
        let port_file = profile.join("DevToolsActivePort");
        let deadline = Instant::now() + START_TIME_LIMIT;
        let (port, path) = loop {
            if let Ok(text) = std::fs::read_to_string(&port_file) {
                let mut lines = text.lines();
                if let (Some(port), Some(path)) = (lines.next(), lines.next()) {
                    break (port.trim().to_owned(), path.trim().to_owned());
                }
            }
            if let Ok(Some(status)) = browser.child.try_wait() {
                return Err(format!(
                    "the browser {program} exited ({status}) before listening; its log:\n{}",
                    tail(&log_path)
                ));
            }
            if Instant::now() > deadline {
                return Err(format!(
                    "the browser {program} did not listen within {START_TIME_LIMIT:?}; its log:\n{}",
                    tail(&log_path)
                ));
            }
            std::thread::sleep(Duration::from_millis(50));
        };
        let stream = TcpStream::connect((
            "127.0.0.1",
            port.parse::<u16>()
                .map_err(|e| format!("bad DevTools port {port:?}: {e}"))?,
        ))
        .map_err(|e| format!("cannot connect to the browser on port {port}: {e}"))?;
        stream
            .set_read_timeout(Some(START_TIME_LIMIT))
            .map_err(|e| e.to_string())?;
        let (socket, _) = tungstenite::client(format!("ws://127.0.0.1:{port}{path}"), stream)
            .map_err(|e| format!("websocket handshake with the browser failed: {e}"))?;
        browser.socket = Some(socket);
        Ok(browser)
    }

    /// Sends a protocol command (to a page when `session` is given) and waits for its
    /// answer until `deadline`, keeping the events that arrive meanwhile.
    fn call(
        &mut self,
        method: &str,
        params: Value,
        session: Option<&str>,
        deadline: Instant,
    ) -> Result<Value, String> {
        self.next_id += 1;
        let id = self.next_id;
        let mut message = json!({ "id": id, "method": method, "params": params });
        if let Some(session) = session {
            message["sessionId"] = json!(session);
        }
        let socket = self.socket.as_mut().ok_or("no connection to the browser")?;
        socket
            .send(Message::text(message.to_string()))
            .map_err(|e| format!("{method}: cannot send: {e}"))?;
        loop {
            let reply = self.read(deadline, method)?;
            if reply.get("id").and_then(Value::as_u64) == Some(id) {
                if let Some(error) = reply.get("error") {
                    return Err(format!("{method} failed: {error}"));
                }
                return Ok(reply.get("result").cloned().unwrap_or(Value::Null));
            }
            if reply.get("method").is_some() {
                self.events.push(reply);
            }
        }
    }

    /// Reads the next protocol message, failing once `deadline` has passed.
    fn read(&mut self, deadline: Instant, waiting_for: &str) -> Result<Value, String> {
        let socket = self.socket.as_mut().ok_or("no connection to the browser")?;
        loop {
            let left = deadline.saturating_duration_since(Instant::now());
            if left.is_zero() {
                return Err(format!("timed out waiting for {waiting_for}"));
            }
            socket
                .get_mut()
                .set_read_timeout(Some(left))
                .map_err(|e| e.to_string())?;
            match socket.read() {
                Ok(Message::Text(text)) => {
                    return serde_json::from_str(text.as_str())
                        .map_err(|e| format!("bad protocol message: {e}"));
                }
                Ok(Message::Close(_)) => return Err("the browser closed the connection".into()),
                Ok(_) => {}
                Err(tungstenite::Error::Io(e))
                    if matches!(e.kind(), ErrorKind::WouldBlock | ErrorKind::TimedOut) =>
                {
                    return Err(format!("timed out waiting for {waiting_for}"));
                }
                Err(e) => return Err(format!("reading from the browser: {e}")),
            }
        }
    }

    /// Lets events that arrived without a command answer be read, for `wait`.
    fn pump(&mut self, wait: Duration) -> Result<(), String> {
        let until = Instant::now() + wait;
        loop {
            match self.read(until, "events") {
                Ok(event) => self.events.push(event),
                Err(e) if e.starts_with("timed out") => return Ok(()),
                Err(e) => return Err(e),
            }
        }
    }

    /// Console errors, uncaught exceptions and error log entries received so far.
    fn page_errors(&self) -> Vec<String> {
        let mut errors = Vec::new();
        for event in &self.events {
            let params = &event["params"];
            match event["method"].as_str() {
                Some("Runtime.exceptionThrown") => {
                    let details = &params["exceptionDetails"];
                    let text = details["exception"]["description"]
                        .as_str()
                        .or_else(|| details["text"].as_str())
                        .unwrap_or("an exception");
                    errors.push(format!("uncaught exception: {text}"));
                }
                Some("Runtime.consoleAPICalled")
                    if matches!(params["type"].as_str(), Some("error" | "assert")) =>
                {
                    let args: Vec<String> = params["args"]
                        .as_array()
                        .into_iter()
                        .flatten()
                        .map(|a| {
                            a["value"]
                                .as_str()
                                .map(str::to_owned)
                                .unwrap_or_else(|| a["description"].to_string())
                        })
                        .collect();
                    errors.push(format!("console.{}: {}", params["type"], args.join(" ")));
                }
                Some("Log.entryAdded") if params["entry"]["level"] == "error" => {
                    errors.push(format!(
                        "log error: {} ({})",
                        params["entry"]["text"], params["entry"]["url"]
                    ));
                }
                _ => {}
            }
        }
        errors
    }
}

/// The last lines of a log file, for error messages.
fn tail(path: &Path) -> String {
    let text = std::fs::read_to_string(path).unwrap_or_default();
    let lines: Vec<&str> = text.lines().collect();
    lines[lines.len().saturating_sub(15)..].join("\n")
}

/// The `file://` URL of an absolute path, percent-encoding every byte but letters,
/// digits, `-._~` and `/`, so a space or `#` in the path cannot change the URL.
fn file_url(path: &Path) -> String {
    let mut url = String::from("file://");
    for b in path.as_os_str().as_encoded_bytes() {
        if b.is_ascii_alphanumeric() || b"-._~/".contains(b) {
            url.push(char::from(*b));
        } else {
            url.push_str(&format!("%{b:02X}"));
        }
    }
    url
}

/// A page opened in its own tab, with helpers that evaluate script in it.
struct Tab<'a> {
    browser: &'a mut Browser,
    session: String,
    target: String,
    deadline: Instant,
}

impl Tab<'_> {
    /// Opens `file` in a new tab with runtime, log and page events on, and waits until
    /// the document has loaded and `ready` (a script expression) is true.
    fn open<'a>(browser: &'a mut Browser, file: &Path, ready: &str) -> Result<Tab<'a>, String> {
        let deadline = Instant::now() + PAGE_TIME_LIMIT;
        browser.events.clear();
        let target = browser.call(
            "Target.createTarget",
            json!({ "url": "about:blank" }),
            None,
            deadline,
        )?;
        let target = target["targetId"]
            .as_str()
            .ok_or("no target id")?
            .to_owned();
        let attached = browser.call(
            "Target.attachToTarget",
            json!({ "targetId": target, "flatten": true }),
            None,
            deadline,
        )?;
        let session = attached["sessionId"]
            .as_str()
            .ok_or("no session id")?
            .to_owned();
        let mut tab = Tab {
            browser,
            session,
            target,
            deadline,
        };
        for domain in ["Runtime.enable", "Log.enable", "Page.enable"] {
            tab.command(domain, json!({}))?;
        }
        let url = file_url(file);
        let navigated = tab.command("Page.navigate", json!({ "url": url }))?;
        if let Some(error) = navigated.get("errorText") {
            return Err(format!("cannot open {url}: {error}"));
        }
        let condition = format!("document.readyState === 'complete' && !!({ready})");
        loop {
            tab.fail_on_errors()?;
            if tab.eval(&condition)? == json!(true) {
                // Events sent while the page loaded arrive before the answer above.
                tab.fail_on_errors()?;
                return Ok(tab);
            }
            if Instant::now() > tab.deadline {
                return Err(format!(
                    "{url}: not ready within {PAGE_TIME_LIMIT:?} ({ready})"
                ));
            }
            std::thread::sleep(Duration::from_millis(100));
        }
    }

    fn command(&mut self, method: &str, params: Value) -> Result<Value, String> {
        let session = self.session.clone();
        self.browser
            .call(method, params, Some(&session), self.deadline)
    }

    /// The value of a script expression (promises awaited), or the exception it threw.
    fn eval(&mut self, expression: &str) -> Result<Value, String> {
        let result = self.command(
            "Runtime.evaluate",
            json!({ "expression": expression, "returnByValue": true, "awaitPromise": true }),
        )?;
        if let Some(details) = result.get("exceptionDetails") {
            return Err(format!("evaluating {expression:?} threw: {details}"));
        }
        Ok(result["result"]["value"].clone())
    }

    fn fail_on_errors(&self) -> Result<(), String> {
        let errors = self.browser.page_errors();
        if errors.is_empty() {
            Ok(())
        } else {
            Err(format!("the page reported errors:\n{}", errors.join("\n")))
        }
    }

    /// A real mouse event at page coordinates.
    fn mouse(&mut self, kind: &str, x: f64, y: f64, buttons: u32) -> Result<(), String> {
        self.command(
            "Input.dispatchMouseEvent",
            json!({ "type": kind, "x": x, "y": y, "button": "left", "buttons": buttons, "clickCount": 1 }),
        )?;
        Ok(())
    }

    fn close(self) -> Result<(), String> {
        let target = self.target.clone();
        let deadline = self.deadline;
        self.browser.call(
            "Target.closeTarget",
            json!({ "targetId": target }),
            None,
            deadline,
        )?;
        Ok(())
    }
}

// ---------------------------------------------------------------------------------
// What is checked on a page.
// ---------------------------------------------------------------------------------

/// Script: statistics of the view canvas's pixels, and a copy kept as `name` for a later
/// comparison. `background` counts pixels equal to the top-left one.
fn snapshot(name: &str) -> String {
    format!(
        "(() => {{ const c = document.getElementById('view');
            const d = c.getContext('2d').getImageData(0, 0, c.width, c.height).data;
            window.{name} = d;
            let other = 0; const colours = new Set();
            for (let i = 0; i < d.length; i += 4) {{
              if (d[i] !== d[0] || d[i + 1] !== d[1] || d[i + 2] !== d[2]) other++;
              if (colours.size < 5000) colours.add((d[i] << 16) | (d[i + 1] << 8) | d[i + 2]);
            }}
            return {{ pixels: d.length / 4, other: other, colours: colours.size }}; }})()"
    )
}

/// Script: how many pixels of the view differ from the copy kept as `name`.
fn changed_since(name: &str) -> String {
    format!(
        "(() => {{ const c = document.getElementById('view');
            const d = c.getContext('2d').getImageData(0, 0, c.width, c.height).data;
            const before = window.{name};
            if (!before || before.length !== d.length) return -1;
            let changed = 0;
            for (let i = 0; i < d.length; i += 4) {{
              if (d[i] !== before[i] || d[i + 1] !== before[i + 1] || d[i + 2] !== before[i + 2]) changed++;
            }}
            return changed; }})()"
    )
}

fn as_u64(v: &Value, what: &str) -> Result<u64, String> {
    v.as_u64()
        .ok_or_else(|| format!("{what}: expected a number, got {v}"))
}

/// What a viewer page check measured.
#[derive(Debug)]
struct PageCheck {
    /// Pixels of the first frame that are not background, of all pixels.
    drawn: u64,
    pixels: u64,
    /// Pixels changed by moving the slider to the last frame, by an orbit drag.
    changed_by_slider: u64,
    changed_by_orbit: u64,
    /// The page's decimation note.
    note: String,
    /// How long the last frame took to draw, in milliseconds (reported, not checked:
    /// timings belong in benchmarks).
    draw_ms: f64,
}

/// Checks a page written into `dir` (a screenshot beside it), failing the test with
/// the page's name on any problem, and prints what was measured.
fn check_written_page(browser: &mut Browser, dir: &Path, page: &PageSummary) -> PageCheck {
    let file = dir.join(&page.file_name);
    let shot = dir.join(format!("{}.png", page.file_name.trim_end_matches(".html")));
    let check = check_viewer_page(browser, &file, &shot)
        .unwrap_or_else(|e| panic!("{}: {e}", page.file_name));
    println!("{}: {check:?}", page.file_name);
    check
}

/// Opens a viewer page and checks everything the module documentation lists.
fn check_viewer_page(
    browser: &mut Browser,
    file: &Path,
    screenshot: &Path,
) -> Result<PageCheck, String> {
    let mut tab = Tab::open(
        browser,
        file,
        "window.sinewViewer && window.sinewViewer.ready",
    )?;
    let page = file.display().to_string();

    // Not blank: many pixels differ from the background, in many colours.
    let first = tab.eval(&snapshot("sinewFirst"))?;
    let (pixels, drawn) = (
        as_u64(&first["pixels"], "pixels")?,
        as_u64(&first["other"], "drawn pixels")?,
    );
    let colours = as_u64(&first["colours"], "colours")?;
    // The axis gizmo alone is a few hundred pixels; a chain with its target path is
    // thousands, a cloth tens of thousands.
    if pixels < 100_000 || drawn < 2000 || colours < 20 {
        return Err(format!(
            "{page}: the view looks blank ({drawn} of {pixels} pixels drawn, {colours} colours)"
        ));
    }

    // The slider, moved as a user would: a new value and an input event.
    let moved = tab.eval(
        "(() => { const s = document.getElementById('timeline');
            s.value = s.max; s.dispatchEvent(new Event('input', { bubbles: true }));
            return Number(s.value); })()",
    )?;
    let last = tab.eval("window.sinewViewer.shownFrames - 1")?;
    if moved != last || moved == json!(0) {
        return Err(format!(
            "{page}: the slider went to {moved}, expected the last frame {last}"
        ));
    }
    let changed_by_slider = as_u64(&tab.eval(&changed_since("sinewFirst"))?, "changed pixels")?;
    if changed_by_slider < 200 {
        return Err(format!(
            "{page}: moving the slider to the last frame changed only {changed_by_slider} pixels"
        ));
    }
    let caption = tab.eval("document.getElementById('caption').textContent")?;
    let total = tab.eval("window.sinewViewer.totalFrames")?;
    if !caption
        .as_str()
        .unwrap_or("")
        .contains(&format!("frame {total} of {total}"))
    {
        return Err(format!("{page}: caption after the slider moved: {caption}"));
    }

    // An orbit: a real mouse drag across the view changes the picture.
    tab.eval(&snapshot("sinewBeforeOrbit"))?;
    let rect = tab.eval(
        "(() => { const r = document.getElementById('view').getBoundingClientRect();
            return [r.left, r.top, r.width, r.height]; })()",
    )?;
    let r: Vec<f64> = rect
        .as_array()
        .ok_or("no canvas rectangle")?
        .iter()
        .filter_map(Value::as_f64)
        .collect();
    let (cx, cy) = (r[0] + 0.5 * r[2], r[1] + 0.5 * r[3]);
    tab.mouse("mousePressed", cx, cy, 1)?;
    for step in 1..=5 {
        tab.mouse(
            "mouseMoved",
            cx + 20.0 * f64::from(step),
            cy + 6.0 * f64::from(step),
            1,
        )?;
    }
    tab.mouse("mouseReleased", cx + 100.0, cy + 30.0, 0)?;
    let changed_by_orbit = as_u64(
        &tab.eval(&changed_since("sinewBeforeOrbit"))?,
        "changed pixels",
    )?;
    if changed_by_orbit < 200 {
        return Err(format!(
            "{page}: an orbit drag changed only {changed_by_orbit} pixels"
        ));
    }

    // A click a quarter of the way along the first chart's plot jumps near that frame.
    let chart = tab.eval(
        "(() => { const c = document.querySelector('.chart canvas');
            if (!c) return null;
            c.scrollIntoView(); const r = c.getBoundingClientRect();
            return [r.left, r.top, r.width, r.height]; })()",
    )?;
    if let Some(rect) = chart.as_array() {
        let r: Vec<f64> = rect.iter().filter_map(Value::as_f64).collect();
        // The plot spans from 58 px to 10 px short of the right edge (the script's PAD).
        let x = r[0] + 58.0 + 0.25 * (r[2] - 68.0);
        let y = r[1] + 0.5 * r[3];
        tab.mouse("mousePressed", x, y, 1)?;
        tab.mouse("mouseReleased", x, y, 0)?;
        let frame =
            tab.eval("window.sinewViewer && Number(document.getElementById('timeline').value)")?;
        let label = tab.eval("document.getElementById('caption').textContent")?;
        let total = as_u64(&total, "total frames")? as f64;
        // The caption's "frame k of n": k should be about a quarter of n.
        let k: f64 = label
            .as_str()
            .and_then(|t| t.strip_prefix("frame "))
            .and_then(|t| t.split_whitespace().next())
            .and_then(|t| t.parse().ok())
            .ok_or_else(|| format!("{page}: caption {label} has no frame number"))?;
        let expected = 1.0 + 0.25 * (total - 1.0);
        if (k - expected).abs() > 0.02 * total + 2.0 || frame == last {
            return Err(format!(
                "{page}: a click at a quarter of the chart went to frame {k} (slider {frame}), expected about {expected:.0}"
            ));
        }
    } else {
        return Err(format!("{page}: no chart"));
    }

    // Play advances the frames; pause stops.
    let before = tab.eval("Number(document.getElementById('timeline').value)")?;
    tab.eval("document.getElementById('play').click()")?;
    // Playback runs on animation frames; a loaded machine may give few, so wait up to
    // five seconds for the first change.
    let mut after = before.clone();
    for _ in 0..50 {
        std::thread::sleep(Duration::from_millis(100));
        after = tab.eval("Number(document.getElementById('timeline').value)")?;
        if after != before {
            break;
        }
    }
    tab.eval("document.getElementById('play').click()")?;
    if after == before {
        return Err(format!("{page}: play did not advance from frame {before}"));
    }

    // The arrow keys step one shown frame; Home goes to the first.
    let at = as_u64(
        &tab.eval("Number(document.getElementById('timeline').value)")?,
        "frame",
    )?;
    for (key, code) in [("ArrowLeft", 37), ("Home", 36), ("ArrowRight", 39)] {
        for kind in ["rawKeyDown", "keyUp"] {
            tab.command(
                "Input.dispatchKeyEvent",
                json!({ "type": kind, "key": key, "code": key, "windowsVirtualKeyCode": code }),
            )?;
        }
    }
    let stepped = tab.eval("Number(document.getElementById('timeline').value)")?;
    if stepped != json!(1) || at == 0 {
        return Err(format!(
            "{page}: from frame {at}, ArrowLeft, Home, ArrowRight went to {stepped}, expected 1"
        ));
    }

    // Nothing fetched: no resource loaded besides the document itself.
    let fetched = tab.eval("performance.getEntriesByType('resource').map(e => e.name)")?;
    if fetched.as_array().is_none_or(|a| !a.is_empty()) {
        return Err(format!("{page}: fetched {fetched}"));
    }

    let note = tab.eval("document.getElementById('decimation').textContent")?;
    let draw_ms = tab
        .eval("window.sinewViewer.lastDrawMs()")?
        .as_f64()
        .unwrap_or(f64::NAN);
    // The screenshot shows a frame a third of the way in, where runs are under way.
    tab.eval(
        "(() => { const s = document.getElementById('timeline');
            s.value = Math.round(s.max / 3); s.dispatchEvent(new Event('input')); })()",
    )?;
    let shot = tab.command("Page.captureScreenshot", json!({ "format": "png" }))?;
    let png = decode_base64(shot["data"].as_str().ok_or("no screenshot data")?);
    if !png.starts_with(b"\x89PNG") {
        return Err(format!("{page}: the screenshot is not a PNG"));
    }
    std::fs::write(screenshot, &png).map_err(|e| e.to_string())?;

    tab.browser.pump(Duration::from_millis(200))?;
    tab.fail_on_errors()?;
    tab.close()?;
    Ok(PageCheck {
        drawn,
        pixels,
        changed_by_slider,
        changed_by_orbit,
        note: note.as_str().unwrap_or("").to_owned(),
        draw_ms,
    })
}

/// Opens the index page and returns the links it holds.
fn check_index(browser: &mut Browser, file: &Path) -> Result<Vec<String>, String> {
    let mut tab = Tab::open(browser, file, "document.getElementById('pages')")?;
    let links =
        tab.eval("Array.from(document.querySelectorAll('a')).map(a => a.getAttribute('href'))")?;
    tab.browser.pump(Duration::from_millis(200))?;
    tab.fail_on_errors()?;
    tab.close()?;
    Ok(links
        .as_array()
        .ok_or("no links")?
        .iter()
        .filter_map(|v| v.as_str().map(str::to_owned))
        .collect())
}

fn decode_base64(text: &str) -> Vec<u8> {
    const ALPHABET: &[u8] = b"ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
    let mut out = Vec::with_capacity(text.len() * 3 / 4);
    let (mut acc, mut bits) = (0u32, 0u32);
    for c in text.bytes() {
        let Some(v) = ALPHABET.iter().position(|&a| a == c) else {
            continue;
        };
        acc = (acc << 6) | v as u32;
        bits += 6;
        if bits >= 8 {
            bits -= 8;
            out.push((acc >> bits) as u8);
        }
    }
    out
}

// ---------------------------------------------------------------------------------
// Realistic synthetic runs.
// ---------------------------------------------------------------------------------

/// A four-joint chain (bones 0.5, 0.4, 0.3) following a five-petal flower path by
/// FABRIK, warm-started from the previous frame; some of the path is out of reach, so
/// the error chart has a shape.
fn ik_track_page(frames: usize) -> ViewerPage {
    let bones = [0.5, 0.4, 0.3];
    let target_at = |k: usize| {
        let theta = std::f64::consts::TAU * k as f64 / frames as f64;
        let r = 0.75 + 0.3 * (5.0 * theta).cos();
        DVec3::new(
            r * theta.cos(),
            0.6 + 0.25 * (3.0 * theta).sin(),
            r * theta.sin(),
        )
    };
    let mut joints = vec![
        DVec3::ZERO,
        DVec3::new(0.0, 0.5, 0.0),
        DVec3::new(0.0, 0.9, 0.0),
        DVec3::new(0.0, 1.2, 0.0),
    ];
    let mut page = ViewerPage::new("flower track: FABRIK, 4 joints", PageKind::IkTrack);
    page.subtitle = "FABRIK, tolerance 1e-4, at most 20 iterations a frame".into();
    page.segments = vec![(0, 1), (1, 2), (2, 3)];
    page.fixed = vec![0];
    page.effectors = vec![3];
    page.target_path = (0..=frames).map(target_at).collect();
    let (mut errors, mut iterations) = (Vec::new(), Vec::new());
    for k in 0..frames {
        let target = target_at(k);
        let mut used = 0;
        for _ in 0..20 {
            if joints[3].distance(target) < 1e-4 {
                break;
            }
            used += 1;
            // Backward pass from the target, forward pass from the fixed root.
            joints[3] = target;
            for j in (0..3).rev() {
                let dir = (joints[j] - joints[j + 1]).normalize_or(DVec3::Y);
                joints[j] = joints[j + 1] + dir * bones[j];
            }
            joints[0] = DVec3::ZERO;
            for j in 0..3 {
                let dir = (joints[j + 1] - joints[j]).normalize_or(DVec3::Y);
                joints[j + 1] = joints[j] + dir * bones[j];
            }
        }
        errors.push(joints[3].distance(target));
        iterations.push(f64::from(used));
        page.frames.push(Frame {
            time: k as f64 / 60.0,
            points: joints.clone(),
            goals: vec![target],
            colliders: Vec::new(),
        });
    }
    let worst = errors.iter().copied().fold(0.0, f64::max);
    page.metrics = vec![
        ("frames".into(), frames.to_string()),
        ("largest error".into(), format!("{worst:.3e} m")),
        (
            "iterations".into(),
            format!("{}", iterations.iter().sum::<f64>()),
        ),
    ];
    let mut error_series = Series::new("effector error", "m", errors);
    error_series.log_scale = true;
    page.charts = vec![error_series, Series::new("iterations", "", iterations)];
    page
}

/// A 21 x 21 cloth (1 m square) dropped onto a sphere, with the ground below and a
/// capsule sweeping under it, stepped by position-based dynamics (structural and shear
/// constraints, collisions projected out).
fn cloth_page(frames: usize) -> ViewerPage {
    let n = 21;
    let spacing = 1.0 / (n - 1) as f64;
    let id = |i: usize, j: usize| i * n + j;
    let mut page = ViewerPage::new("cloth on a sphere: 21 x 21", PageKind::Cloth);
    page.subtitle = "position-based test cloth, 4 substeps a frame".into();
    for i in 0..n {
        for j in 0..n {
            for (di, dj) in [(0, 1), (1, 0), (1, 1)] {
                if i + di < n && j + dj < n {
                    page.segments.push((id(i, j), id(i + di, j + dj)));
                }
            }
            if i + 1 < n && j >= 1 {
                page.segments.push((id(i, j), id(i + 1, j - 1)));
            }
            if i + 1 < n && j + 1 < n {
                page.triangles
                    .push([id(i, j), id(i + 1, j), id(i + 1, j + 1)]);
                page.triangles
                    .push([id(i, j), id(i + 1, j + 1), id(i, j + 1)]);
            }
        }
    }
    let mut x: Vec<DVec3> = (0..n * n)
        .map(|p| {
            DVec3::new(
                -0.5 + spacing * (p % n) as f64,
                1.0,
                -0.5 + spacing * (p / n) as f64,
            )
        })
        .collect();
    page.rest_lengths = page
        .segments
        .iter()
        .map(|&(i, j)| x[i].distance(x[j]))
        .collect();
    let mut previous = x.clone();
    let (sphere_centre, sphere_radius) = (DVec3::new(0.0, 0.45, 0.0), 0.3);
    let capsule_at = |t: f64| {
        let z = -0.8 + 1.6 * (t / (frames as f64 / 60.0));
        (DVec3::new(-0.7, 0.12, z), DVec3::new(0.7, 0.12, z), 0.1)
    };
    let (dt, substeps, gravity) = (1.0 / 60.0, 4, DVec3::new(0.0, -9.81, 0.0));
    let h = dt / f64::from(substeps);
    let mass = 1.0 / (n * n) as f64;
    let mut energy = Vec::new();
    let mut lowest: f64 = f64::INFINITY;
    for k in 0..frames {
        let t = k as f64 * dt;
        let (a, b, r) = capsule_at(t);
        page.frames.push(Frame {
            time: t,
            points: x.clone(),
            goals: Vec::new(),
            colliders: vec![
                Collider::HalfSpace {
                    point: DVec3::ZERO,
                    normal: DVec3::Y,
                },
                Collider::Sphere {
                    center: sphere_centre,
                    radius: sphere_radius,
                },
                Collider::Capsule { a, b, radius: r },
            ],
        });
        let kinetic: f64 = x
            .iter()
            .zip(&previous)
            .map(|(p, q)| 0.5 * mass * ((*p - *q) / h).length_squared())
            .sum();
        let potential: f64 = x.iter().map(|p| mass * 9.81 * p.y).sum();
        energy.push(kinetic + potential);
        for _ in 0..substeps {
            for (p, q) in x.iter_mut().zip(previous.iter_mut()) {
                let velocity = (*p - *q) * 0.995;
                *q = *p;
                *p += velocity + gravity * h * h;
            }
            for _ in 0..8 {
                for (&(i, j), &rest) in page.segments.iter().zip(&page.rest_lengths) {
                    let d = x[j] - x[i];
                    let len = d.length();
                    if len > 1e-12 {
                        let correction = d * (0.5 * (len - rest) / len);
                        x[i] += correction;
                        x[j] -= correction;
                    }
                }
                for p in x.iter_mut() {
                    let from_centre = *p - sphere_centre;
                    let reach = sphere_radius + 0.01;
                    if from_centre.length() < reach {
                        *p = sphere_centre + from_centre.normalize_or(DVec3::Y) * reach;
                    }
                    let axis = b - a;
                    let s = ((*p - a).dot(axis) / axis.length_squared()).clamp(0.0, 1.0);
                    let from_axis = *p - (a + axis * s);
                    if from_axis.length() < r + 0.01 {
                        *p = a + axis * s + from_axis.normalize_or(DVec3::Y) * (r + 0.01);
                    }
                    p.y = p.y.max(0.005);
                }
            }
        }
        lowest = lowest.min(x.iter().map(|p| p.y).fold(f64::INFINITY, f64::min));
    }
    page.metrics = vec![
        ("particles".into(), (n * n).to_string()),
        ("constraints".into(), page.segments.len().to_string()),
        ("lowest particle".into(), format!("{lowest:.4} m")),
        (
            "final energy".into(),
            format!("{:.4} J", energy.last().unwrap()),
        ),
    ];
    page.charts = vec![Series::new("energy (kinetic + gravity)", "J", energy)];
    page
}

/// A full-body clip: a stick figure (pelvis, spine, neck, head, two arms, two legs; 15
/// joints in a tree) walking on the spot and waving, with a goal on each hand.
fn clip_page(frames: usize) -> ViewerPage {
    // Parents in topological order and the rest offset of each joint from its parent.
    let joints: [(usize, DVec3); 15] = [
        (0, DVec3::new(0.0, 0.95, 0.0)), // 0 pelvis (its own parent: the root)
        (0, DVec3::new(0.0, 0.25, 0.0)), // 1 spine
        (1, DVec3::new(0.0, 0.25, 0.0)), // 2 neck
        (2, DVec3::new(0.0, 0.15, 0.0)), // 3 head
        (2, DVec3::new(0.18, -0.02, 0.0)), // 4 right shoulder
        (4, DVec3::new(0.0, -0.28, 0.0)), // 5 right elbow
        (5, DVec3::new(0.0, -0.25, 0.0)), // 6 right hand
        (2, DVec3::new(-0.18, -0.02, 0.0)), // 7 left shoulder
        (7, DVec3::new(0.0, -0.28, 0.0)), // 8 left elbow
        (8, DVec3::new(0.0, -0.25, 0.0)), // 9 left hand
        (0, DVec3::new(0.1, -0.05, 0.0)), // 10 right hip
        (10, DVec3::new(0.0, -0.45, 0.0)), // 11 right knee
        (11, DVec3::new(0.0, -0.42, 0.0)), // 12 right foot
        (0, DVec3::new(-0.1, -0.05, 0.0)), // 13 left hip
        (13, DVec3::new(0.0, -0.45, 0.0)), // 14 left knee
    ];
    let mut page = ViewerPage::new("stick figure: walk and wave", PageKind::Clip);
    page.subtitle = "15 joints, two hand goals".into();
    page.segments = (1..joints.len()).map(|j| (joints[j].0, j)).collect();
    page.effectors = vec![6, 9];
    let mut reach = Vec::new();
    for k in 0..frames {
        let t = k as f64 / 30.0;
        let swing = 0.6 * (std::f64::consts::TAU * t).sin();
        let wave = 1.2 + 0.8 * (2.0 * std::f64::consts::TAU * t).sin();
        // Each joint turns about x (legs and left arm swing) or z (right arm waves).
        let turn = |j: usize| match j {
            4 => sinew_math::DQuat::from_rotation_z(wave),
            7 | 10 => sinew_math::DQuat::from_rotation_x(-swing),
            13 => sinew_math::DQuat::from_rotation_x(swing),
            11 | 14 => sinew_math::DQuat::from_rotation_x(0.4 * swing.abs()),
            _ => sinew_math::DQuat::IDENTITY,
        };
        let mut rotation = vec![sinew_math::DQuat::IDENTITY; joints.len()];
        let mut points = vec![DVec3::ZERO; joints.len()];
        points[0] =
            joints[0].1 + DVec3::new(0.0, 0.02 * (2.0 * std::f64::consts::TAU * t).cos(), 0.0);
        rotation[0] = turn(0);
        for j in 1..joints.len() {
            let (parent, offset) = joints[j];
            rotation[j] = rotation[parent] * turn(j);
            points[j] = points[parent] + rotation[parent] * offset;
        }
        let goals = vec![
            DVec3::new(0.55, 1.75 + 0.1 * (std::f64::consts::TAU * t).sin(), 0.0),
            DVec3::new(-0.3, 0.9, 0.25),
        ];
        reach.push(points[6].distance(goals[0]));
        page.frames.push(Frame {
            time: t,
            points,
            goals,
            colliders: vec![Collider::HalfSpace {
                point: DVec3::ZERO,
                normal: DVec3::Y,
            }],
        });
    }
    page.charts = vec![Series::new("right hand to its goal", "m", reach)];
    page.metrics = vec![
        ("joints".into(), joints.len().to_string()),
        ("frames".into(), frames.to_string()),
    ];
    page
}

/// Writes the pages and the index into a fresh directory under the test's target
/// directory.
fn write_pages(dir: &Path) -> Vec<PageSummary> {
    let _ = std::fs::remove_dir_all(dir);
    let ik = write_page(
        dir,
        "ik-flower.html",
        &ik_track_page(240),
        &Budget::default(),
    )
    .unwrap();
    // A small budget, so the cloth page is decimated and says so.
    let budget = Budget {
        max_bytes: 800_000,
        max_frames: 1000,
    };
    let cloth = write_page(dir, "cloth-sphere.html", &cloth_page(300), &budget).unwrap();
    assert!(cloth.shown_frames < cloth.total_frames, "{cloth:?}");
    assert!(cloth.bytes <= 800_000, "{cloth:?}");
    let clip = write_page(dir, "clip-walk.html", &clip_page(90), &Budget::default()).unwrap();
    let pages = vec![ik, cloth, clip];
    write_scene_index(dir, "synthetic", &pages).unwrap();
    pages
}

#[test]
fn viewer_pages_work_in_headless_chromium() {
    let _one_at_a_time = BROWSER_LOCK.lock().unwrap_or_else(|e| e.into_inner());
    let dir = PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join("viewer-pages");
    let pages = write_pages(&dir);
    let mut browser = Browser::start("pages").unwrap_or_else(|e| panic!("headless Chromium: {e}"));
    for page in &pages {
        let check = check_written_page(&mut browser, &dir, page);
        let expected = if page.shown_frames == page.total_frames {
            format!("showing all {} frames", page.total_frames)
        } else {
            format!(
                "showing {} of {} frames",
                page.shown_frames, page.total_frames
            )
        };
        assert!(
            check.note.starts_with(&expected),
            "{}: note {:?}",
            page.file_name,
            check.note
        );
        assert!(check.drawn <= check.pixels);
        assert!(check.changed_by_slider > 0 && check.changed_by_orbit > 0);
        assert!(
            check.draw_ms.is_finite() && check.draw_ms >= 0.0,
            "{check:?}"
        );
    }
    let links = check_index(&mut browser, &dir.join("index.html"))
        .unwrap_or_else(|e| panic!("index.html: {e}"));
    let expected: Vec<String> = pages.iter().map(|p| p.file_name.clone()).collect();
    assert_eq!(links, expected);
    for link in &links {
        assert!(
            dir.join(link).is_file(),
            "the index links to {link}, which does not exist"
        );
    }
}

/// The pages `cargo xtask run-scene` writes for the lab scene (scenes/lab4.ron): every
/// IK track and cloth page, converted from the run's results, passes the same checks,
/// and the index links exactly them.
#[test]
fn lab_scene_pages_work_in_headless_chromium() {
    let _one_at_a_time = BROWSER_LOCK.lock().unwrap_or_else(|e| e.into_inner());
    let dir = PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join("viewer-lab4");
    let _ = std::fs::remove_dir_all(&dir);
    let scene_file = concat!(env!("CARGO_MANIFEST_DIR"), "/../../scenes/lab4.ron");
    let scene = sinew_scene::Scene::from_file(scene_file).unwrap_or_else(|e| panic!("{e}"));
    let results = scene.run(&sinew_scene::RunOptions {
        keep_frames: true,
        ..sinew_scene::RunOptions::default()
    });
    assert!(results.ok(), "lab4 runs and meets its expectations");
    let mut pages = Vec::new();
    for task in &results.tasks {
        if let Some(page) = sinew_viz::render::viewer_page(task) {
            let file = format!("{}.html", task.name);
            pages.push(write_page(&dir, &file, &page, &Budget::default()).unwrap());
        }
    }
    // Every IK task that tracks more than one target and every cloth is animated.
    let animated = results
        .tasks
        .iter()
        .filter(|t| match &t.metrics {
            sinew_scene::TaskMetrics::Ik(m) => m.frames > 1,
            sinew_scene::TaskMetrics::Cloth(m) => m.run.steps > 0,
            _ => false,
        })
        .count();
    assert!(animated >= 8, "lab4 has its IK tracks and cloths");
    assert_eq!(
        pages.len(),
        animated,
        "a page per animated IK and cloth task"
    );
    write_scene_index(&dir, &results.scene, &pages).unwrap();
    let mut browser = Browser::start("lab4").unwrap_or_else(|e| panic!("headless Chromium: {e}"));
    for page in &pages {
        let check = check_written_page(&mut browser, &dir, page);
        assert_eq!(page.shown_frames, page.total_frames, "{page:?}");
        assert!(check.changed_by_slider > 0 && check.changed_by_orbit > 0);
    }
    let links = check_index(&mut browser, &dir.join("index.html"))
        .unwrap_or_else(|e| panic!("index.html: {e}"));
    let expected: Vec<String> = pages.iter().map(|p| p.file_name.clone()).collect();
    assert_eq!(links, expected);
}

/// The checks themselves can fail: a page that logs a console error, one that throws,
/// and one whose canvas stays blank are each rejected with a message saying why.
#[test]
fn broken_pages_are_caught() {
    let _one_at_a_time = BROWSER_LOCK.lock().unwrap_or_else(|e| e.into_inner());
    let dir = PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join("viewer-broken");
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    let ready = "<canvas id=\"view\" width=\"800\" height=\"600\"></canvas>\
        <script>window.sinewViewer = { ready: true, shownFrames: 2, totalFrames: 2 };</script>";
    let cases = [
        (
            "console-error.html",
            format!("{ready}<script>console.error('broken on purpose');</script>"),
            "broken on purpose",
        ),
        (
            "exception.html",
            format!("{ready}<script>null.missing();</script>"),
            "uncaught exception",
        ),
        ("blank.html", ready.to_owned(), "looks blank"),
    ];
    let mut browser = Browser::start("broken").unwrap_or_else(|e| panic!("headless Chromium: {e}"));
    for (name, html, expected) in cases {
        let file = dir.join(name);
        std::fs::write(&file, format!("<!DOCTYPE html><html><head><link rel=\"icon\" href=\"data:,\"></head><body>{html}</body></html>")).unwrap();
        let err = check_viewer_page(&mut browser, &file, &dir.join("shot.png"))
            .expect_err(&format!("{name} passed the checks"));
        assert!(err.contains(expected), "{name}: {err}");
    }
}

/// With no browser to start, the test fails and says so, rather than skipping.
#[test]
fn a_missing_browser_is_an_error_not_a_skip() {
    let err = match Browser::start_program("/nonexistent/chromium", "missing") {
        Ok(_) => panic!("a browser started from a path that does not exist"),
        Err(e) => e,
    };
    assert!(
        err.contains("cannot start the browser /nonexistent/chromium"),
        "{err}"
    );
    let workdir = PathBuf::from(env!("CARGO_TARGET_TMPDIR"))
        .join(format!("chromium-missing-{}", std::process::id()));
    assert!(!workdir.exists(), "{} left behind", workdir.display());

    // A program that starts but exits at once is reported, not waited for until the
    // time limit.
    let started = Instant::now();
    let err = match Browser::start_program("false", "exits") {
        Ok(_) => panic!("`false` was taken for a browser"),
        Err(e) => e,
    };
    assert!(
        err.contains("exited") && err.contains("before listening"),
        "{err}"
    );
    assert!(
        started.elapsed() < START_TIME_LIMIT,
        "waited {:?}",
        started.elapsed()
    );
}
