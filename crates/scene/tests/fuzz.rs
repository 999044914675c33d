//! Scene files cannot crash the runner: every shipped scene (`scenes/`, `scenes/long/`,
//! `scenes/bad/`) is mutated (bytes flipped, the file cut short, lines swapped or
//! duplicated, numbers made huge, tiny, NaN or infinite in every spelling RON accepts,
//! brackets nested deeply) and each mutant is read and checked. The property: a located
//! error (file:line:col, or the task and the field) or a scene that validates, never a
//! panic, and never longer than a time limit. The mutants of the small scenes that
//! validate are also run, each at a pace (time per step or frame of each task) within
//! twenty times its original's, and stopped at a time budget scaled from its original's
//! run (a mutant may ask for many more steps: done at pace, that is not a hang). Pace and
//! budget grow with the mutant's size (its cloth particles) over its original's: a
//! mutant may ask for larger steps too.
//!
//! Over pace is stricter than a hang: a valid mutant can make the physics far harder
//! (a stiffness raised a million times, a step of 1e9 s), and the steps then converge
//! at many times the original's cost. CI fails on it all the same, on its fixed cases.
//! A deep run may set `SINEW_FUZZ_SLOW=report` to list such runs at the end instead of
//! failing on them; a hang (no unit of work ending within [`HANG_LIMIT`]), a panic and
//! an error without a location still fail.
//!
//! Cases come from a fixed seed, so CI sees the same ones every time;
//! `SINEW_FUZZ_CASES` sets how many (default 300), `SINEW_FUZZ_SEED` the seed and
//! `SINEW_FUZZ_RUNS` the most mutants run (default: every one that validates of a small
//! scene; 0 for a deep run of reading and checking alone). The deep run's count, time
//! and result are in docs/labcheck.md ("Runs").

use sinew_scene::schema::Task;
use sinew_scene::tasks::cloth::SystemSpec;
use sinew_scene::tasks::mesh_cloth::SheetSpec;
use sinew_scene::{RunOptions, Scene, SceneError};
use std::path::{Path, PathBuf};
use std::sync::mpsc;
use std::time::{Duration, Instant};

/// The default number of cases (CI's).
const DEFAULT_CASES: usize = 300;
/// The default seed.
const DEFAULT_SEED: u64 = 0x5CE7_E0F0_2026;
/// Reading and checking one mutant may take this long (a shipped scene takes
/// milliseconds; the limit is for a slow, loaded machine).
const VALIDATE_LIMIT: Duration = Duration::from_secs(20);
/// A scene whose unmutated run takes less than this is small: its mutants that validate
/// are run too.
const SMALL_RUN: Duration = Duration::from_millis(1500);

/// A deterministic generator (xorshift64*): the cases are the same on every machine.
struct Cases(u64);

impl Cases {
    fn next(&mut self) -> u64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        self.0.wrapping_mul(0x2545_F491_4F6C_DD1D)
    }

    /// Uniform in `0..n` (n > 0).
    fn below(&mut self, n: usize) -> usize {
        (self.next() % n as u64) as usize
    }

    fn pick<'a, T>(&mut self, items: &'a [T]) -> &'a T {
        &items[self.below(items.len())]
    }
}

/// Numbers a mutation puts in place of a number: absurd sizes, the extremes of the
/// integer and float types, values that overflow them, and NaN and infinity in every
/// spelling RON 0.12 accepts.
const NUMBERS: &[&str] = &[
    "0",
    "-0",
    "-1",
    "1e9",
    "1e12",
    "1e300",
    "-1e300",
    "1e-300",
    "5e-324",
    "1e400",
    "-1e400",
    "1.7976931348623157e308",
    "4294967295",
    "4294967296",
    "9223372036854775807",
    "18446744073709551615",
    "18446744073709551616",
    "1000000",
    "100000000",
    "inf",
    "+inf",
    "-inf",
    "NaN",
    "+NaN",
    "-NaN",
    "inff64",
    "-inff64",
    "NaNf64",
    "inff32",
    "NaNf32",
    "0x7fffffffffffffff",
    "1_000_000_000",
];

/// What was done to a scene (printed with a failure, so it can be reproduced by hand).
#[derive(Debug)]
#[allow(
    dead_code,
    reason = "the fields are read through Debug, in failure messages"
)]
enum Mutation {
    FlipByte { at: usize, to: u8 },
    Truncate { at: usize },
    SwapLines { a: usize, b: usize },
    DuplicateLine { line: usize },
    DeleteLine { line: usize },
    Number { at: usize, with: &'static str },
    Nest { at: usize, depth: usize, open: char },
}

fn mutate(text: &str, cases: &mut Cases) -> (Mutation, Vec<u8>) {
    let bytes = text.as_bytes();
    let lines: Vec<&str> = text.split_inclusive('\n').collect();
    let join = |lines: &[&str]| lines.concat().into_bytes();
    match cases.below(8) {
        0 | 1 => {
            let at = cases.below(bytes.len());
            // Mostly printable ASCII (syntax), sometimes any byte (invalid UTF-8).
            let to = if cases.below(4) == 0 {
                cases.next() as u8
            } else {
                b' ' + cases.below(95) as u8
            };
            let mut out = bytes.to_vec();
            out[at] = to;
            (Mutation::FlipByte { at, to }, out)
        }
        2 => {
            let at = cases.below(bytes.len());
            (Mutation::Truncate { at }, bytes[..at].to_vec())
        }
        3 => {
            let (a, b) = (cases.below(lines.len()), cases.below(lines.len()));
            let mut swapped = lines.clone();
            swapped.swap(a, b);
            (Mutation::SwapLines { a, b }, join(&swapped))
        }
        4 => {
            let line = cases.below(lines.len());
            let mut more = lines.clone();
            more.insert(line, lines[line]);
            (Mutation::DuplicateLine { line }, join(&more))
        }
        5 => {
            let line = cases.below(lines.len());
            let mut fewer = lines.clone();
            fewer.remove(line);
            (Mutation::DeleteLine { line }, join(&fewer))
        }
        6 => {
            let numbers = number_spans(text);
            if numbers.is_empty() {
                let at = cases.below(bytes.len());
                return (Mutation::Truncate { at }, bytes[..at].to_vec());
            }
            let (start, end) = *cases.pick(&numbers);
            let with = *cases.pick(NUMBERS);
            let mut out = bytes[..start].to_vec();
            out.extend_from_slice(with.as_bytes());
            out.extend_from_slice(&bytes[end..]);
            (Mutation::Number { at: start, with }, out)
        }
        _ => {
            let at = cases.below(bytes.len() + 1);
            let at = (0..=at)
                .rev()
                .find(|&i| text.is_char_boundary(i))
                .unwrap_or(0);
            let depth = *cases.pick(&[64, 200, 5_000, 100_000]);
            let open = *cases.pick(&['(', '[', '{']);
            let mut out = bytes[..at].to_vec();
            out.extend(std::iter::repeat_n(open as u8, depth));
            out.extend_from_slice(&bytes[at..]);
            (Mutation::Nest { at, depth, open }, out)
        }
    }
}

/// Byte ranges of the number literals of `text` (a digit run with its sign, point,
/// exponent and underscores, not part of a name).
fn number_spans(text: &str) -> Vec<(usize, usize)> {
    let b = text.as_bytes();
    let mut spans = Vec::new();
    let mut i = 0;
    while i < b.len() {
        let starts = b[i].is_ascii_digit()
            && (i == 0 || !(b[i - 1].is_ascii_alphanumeric() || b[i - 1] == b'_'));
        if !starts {
            i += 1;
            continue;
        }
        let start = if i > 0 && b[i - 1] == b'-' { i - 1 } else { i };
        let mut end = i;
        while end < b.len()
            && (b[end].is_ascii_digit()
                || matches!(b[end], b'.' | b'e' | b'E' | b'_')
                || (matches!(b[end], b'-' | b'+') && matches!(b[end - 1], b'e' | b'E')))
        {
            end += 1;
        }
        spans.push((start, end));
        i = end;
    }
    spans
}

/// Whether an error says where: a parse error's line and column, or the task and the
/// field (`steps = ...`, `system: ...`, `pose[2]: ...`) of a bad value.
fn located(error: &SceneError) -> bool {
    match error {
        SceneError::Parse { line, col, .. } => *line >= 1 && *col >= 1,
        SceneError::Invalid { task, message, .. } => {
            let field: String = message
                .chars()
                .take_while(|c| c.is_ascii_alphanumeric() || matches!(c, '_' | '[' | ']' | '.'))
                .collect();
            let rest = &message[field.len()..];
            // The one error about the task itself: its name repeats another's.
            let duplicate = message.starts_with("another task has the same name");
            // A library's error that names the field in its own words, e.g. "two-bone IK
            // `hinge.min` has a NaN or infinite component".
            let quoted = message.split('`').skip(1).step_by(2).any(|name| {
                !name.is_empty()
                    && name
                        .chars()
                        .all(|c| c.is_ascii_alphanumeric() || matches!(c, '_' | '.' | '[' | ']'))
            });
            duplicate
                || (!task.is_empty() && quoted)
                || (!task.is_empty()
                    && !field.is_empty()
                    && field.starts_with(|c: char| c.is_ascii_lowercase())
                    && (rest.starts_with(": ") || rest.starts_with(" = ")))
        }
        SceneError::Io { .. } => false,
    }
}

/// Runs `f` on its own thread and waits at most `limit`: `None` if it did not finish
/// (the thread is left behind; the test fails), `Some(Err(panic message))` if it
/// panicked; a run stopped by the test's own [`Stop`] payload is `Some(Err(...))` with
/// that stop's words, not a panic.
fn within<T: Send + 'static>(
    limit: Duration,
    f: impl FnOnce() -> T + Send + 'static,
) -> Option<Result<T, String>> {
    let (send, receive) = mpsc::channel();
    std::thread::Builder::new()
        .name("fuzz case".into())
        .spawn(move || {
            let outcome = std::panic::catch_unwind(std::panic::AssertUnwindSafe(f)).map_err(|p| {
                if let Some(stop) = p.downcast_ref::<Stop>() {
                    return stop.words();
                }
                p.downcast_ref::<String>()
                    .cloned()
                    .or_else(|| p.downcast_ref::<&str>().map(|s| s.to_string()))
                    .unwrap_or_else(|| "a panic".into())
            });
            let _ = send.send(outcome);
        })
        .expect("a thread for the case");
    receive.recv_timeout(limit).ok()
}

/// The payload of the unwinding that stops a run from its progress callback (so a run
/// stopped by the test does not run on in the background).
enum Stop {
    /// A task ran more than twenty times slower per unit of work (step, frame) than the
    /// same task of the original: the sentence says which, and how slow.
    OverPace(String),
    /// The run reached its time budget at an acceptable pace: it asked for more units of
    /// work than the original (a step count made larger) and was doing them at most
    /// twenty times slower each. Not a failure.
    OnPace,
}

/// What [`within`] reports for a run stopped on pace.
const ON_PACE: &str = "stopped on pace at its time budget";
/// The start of what [`within`] reports for a run stopped over pace.
const OVER_PACE: &str = "over pace";

impl Stop {
    fn words(&self) -> String {
        match self {
            Self::OverPace(why) => format!("{OVER_PACE}: {why}"),
            Self::OnPace => ON_PACE.to_string(),
        }
    }
}

/// How fast an original scene ran: per task, the time per unit of progress after its
/// first (the time from its first unit to its last over the units in between), and the
/// slowest of them (for a task whose name a mutation changed). What comes before a
/// task's first unit (its set-up, and the tasks that report no progress: forward
/// kinematics, curves) is bounded by the run's time budget instead.
#[derive(Clone, Debug)]
struct Pace {
    per_unit: Vec<(String, Duration)>,
    slowest: Duration,
}

impl Pace {
    fn per_unit(&self, task: &str) -> Duration {
        self.per_unit
            .iter()
            .find(|(name, _)| name == task)
            .map_or(self.slowest, |(_, d)| *d)
    }
}

/// A mutant's task may take this many times the original task's time per unit of work
/// (times the growth of its size, [`size`]) ...
const PACE_FACTOR: u32 = 20;
/// ... plus this (a loaded machine, a task's set-up before its first unit).
const PACE_SLACK: Duration = Duration::from_secs(2);
/// A mutant's time budget grows with its size ([`size`]) up to this: a grown grid's
/// set-up and first steps are watched, not its whole run.
const MAX_BUDGET: Duration = Duration::from_secs(60);
/// A run that has neither finished nor been stopped by its progress callback after
/// twice its budget and ten seconds, and at least this long, is a hang: no unit of its
/// work came to an end. (A single step can legitimately take a minute: the 101 x 101
/// sheet of `cloth-big` with a step of 1e9 s, a static solve of 30 603 unknowns from the
/// flat sheet, takes 421 Newton iterations in its first: about 47 s run alone by `cargo
/// xtask run-scene` (50.7 s for the run, whose other 29 steps take one iteration each,
/// about 0.1 s), and its first step ended 82 s into the run within this test.)
const HANG_LIMIT: Duration = Duration::from_secs(300);

/// The size of a scene's work per unit (step, frame): the particles of its cloth tasks
/// (grid sheets, explicit particles), at least 1. A digit flipped in a grid's `size` is
/// within the limits and makes every step hundreds of times costlier; a mutant's pace
/// and budget are scaled by its size over its original's, linearly (a step of the
/// implicit integrators costs at least its particles' assembly; the grid grown from 32
/// to 732 measured 0.81 microseconds per particle-step against the original's 0.48).
/// Other task kinds count 1: their cost per frame is microseconds, within the slack.
/// An OBJ sheet counts 1 too: the mutations change the scene file, not the mesh.
fn size(scene: &Scene) -> f64 {
    let particles: usize = scene
        .tasks
        .iter()
        .map(|task| match task {
            Task::Cloth(t) => match &t.system {
                SystemSpec::Grid(grid) => grid.size.saturating_mul(grid.size),
                SystemSpec::Explicit { particles, .. } => particles.len(),
            },
            Task::MeshCloth(t) => t
                .sheets
                .iter()
                .map(|sheet| match sheet {
                    SheetSpec::Grid { size, .. } => size.saturating_mul(*size),
                    SheetSpec::Obj { .. } => 1,
                })
                .sum(),
            _ => 0,
        })
        .sum();
    particles.max(1) as f64
}

/// The progress seen so far by a run's callback: the current task and the time of its
/// first unit.
struct Seen {
    task: String,
    first_unit: Instant,
}

impl Seen {
    fn new() -> Self {
        Self {
            task: String::new(),
            first_unit: Instant::now(),
        }
    }

    /// Notes a unit of `task` at `now`; returns the time since the task's first unit
    /// (zero at its first).
    fn note(&mut self, task: &str, now: Instant) -> Duration {
        if task != self.task {
            self.task = task.to_string();
            self.first_unit = now;
        }
        now - self.first_unit
    }
}

/// Runs an original scene within `limit`, measuring its time and pace (`None` if it did
/// not finish in time).
fn measure(scene: Scene, limit: Duration) -> Option<(Duration, Pace)> {
    let outcome = within(limit * 2 + Duration::from_secs(10), move || {
        let start = Instant::now();
        let seen = std::cell::RefCell::new(Seen::new());
        // Per task: its name, the time from its first unit to its last, and the units
        // after the first.
        let tasks = std::cell::RefCell::new(Vec::<(String, Duration, usize)>::new());
        let record = |task: &str, done: usize, _total: usize| {
            let since_first = seen.borrow_mut().note(task, Instant::now());
            let mut tasks = tasks.borrow_mut();
            match tasks.last_mut() {
                Some(last) if last.0 == task => (last.1, last.2) = (since_first, done - 1),
                _ => tasks.push((task.to_string(), Duration::ZERO, 0)),
            }
        };
        let _ = scene.run(&RunOptions {
            progress: Some(&record),
            ..RunOptions::default()
        });
        let per_unit: Vec<(String, Duration)> = tasks
            .into_inner()
            .into_iter()
            .map(|(name, time, after_first)| (name, time / after_first.max(1) as u32))
            .collect();
        let slowest = per_unit.iter().map(|(_, d)| *d).max().unwrap_or_default();
        (start.elapsed(), Pace { per_unit, slowest })
    });
    match outcome {
        Some(Ok((time, pace))) if time <= limit => Some((time, pace)),
        _ => None,
    }
}

/// Runs a mutant on its own thread with a budget of `budget`: `Some(Ok(()))` when it
/// finished, `Some(Err(words))` when it was stopped ([`Stop`]) or panicked, `None` when
/// it did not even stop (a unit of work that never ends). At every unit of work after a
/// task's first, the time since that first unit is compared with [`PACE_FACTOR`] times
/// the original task's time per unit, times the units since, plus [`PACE_SLACK`]: above
/// it the run is over pace. A task's first unit must come within the budget (it
/// follows its set-up and the tasks that report no progress). A run within pace that
/// reaches the budget is stopped on pace: a mutant may ask for many more steps than its
/// original, and doing them at the original's pace is not a hang.
fn run_paced(
    scene: Scene,
    pace: Pace,
    growth: f64,
    budget: Duration,
) -> Option<Result<(), String>> {
    within(
        (budget * 2 + Duration::from_secs(10)).max(HANG_LIMIT),
        move || {
            let start = Instant::now();
            let seen = std::cell::RefCell::new(Seen::new());
            let check = |task: &str, done: usize, total: usize| {
                let now = Instant::now();
                let first = task != seen.borrow().task;
                let since_first = seen.borrow_mut().note(task, now);
                if first && now - start > budget {
                    std::panic::panic_any(Stop::OverPace(format!(
                        "task {task:?}: its first unit came after {:?}, over the run's budget of \
                     {budget:?}",
                        now - start
                    )));
                }
                let units = (done - 1) as u32;
                let per_unit = pace.per_unit(task).mul_f64(growth);
                let allowed = per_unit * PACE_FACTOR * units + PACE_SLACK;
                if since_first > allowed {
                    std::panic::panic_any(Stop::OverPace(format!(
                        "task {task:?}: {units} units after its first (of {total}) in \
                     {since_first:?}, allowed {allowed:?} ({PACE_FACTOR} times the \
                     original's {:?} per unit times the size's growth {growth}, plus \
                     {PACE_SLACK:?})",
                        pace.per_unit(task)
                    )));
                }
                if now - start > budget {
                    std::panic::panic_any(Stop::OnPace);
                }
            };
            let _ = scene.run(&RunOptions {
                progress: Some(&check),
                ..RunOptions::default()
            });
        },
    )
}

/// Reads mutated bytes as the runner does: invalid UTF-8 is a located error too.
fn load(path: &Path, bytes: Vec<u8>) -> Result<Scene, SceneError> {
    Scene::from_bytes(path, &bytes)
}

/// The repository's `scenes/` folder.
fn scenes_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../../scenes")
}

fn scene_files() -> Vec<PathBuf> {
    let root = scenes_dir();
    let mut files = Vec::new();
    for dir in [root.clone(), root.join("long"), root.join("bad")] {
        for entry in std::fs::read_dir(&dir).expect("the scenes directory") {
            let path = entry.expect("a directory entry").path();
            if path.extension().is_some_and(|x| x == "ron") {
                files.push(path);
            }
        }
    }
    files.sort();
    files
}

fn env_or<T: std::str::FromStr>(name: &str, default: T) -> T {
    match std::env::var(name) {
        Ok(v) => v
            .trim()
            .parse()
            .unwrap_or_else(|_| panic!("{name} = {v:?} is not a number")),
        Err(_) => default,
    }
}

/// An original scene: its text and, for a small scene that validates, how long its
/// unmutated run took and at what pace.
struct Original {
    path: PathBuf,
    text: String,
    run_time: Option<(Duration, Pace)>,
    /// Its [`size`] (1 if it does not load).
    size: f64,
}

#[test]
fn mutated_scenes_give_a_located_error_or_validate_and_run_in_bounded_time() {
    let count: usize = env_or("SINEW_FUZZ_CASES", DEFAULT_CASES);
    let seed: u64 = env_or("SINEW_FUZZ_SEED", DEFAULT_SEED);
    let max_runs: usize = env_or("SINEW_FUZZ_RUNS", usize::MAX);
    let report_slow = match std::env::var("SINEW_FUZZ_SLOW").as_deref() {
        Ok("report") => true,
        Ok("fail") | Err(_) => false,
        Ok(other) => panic!("SINEW_FUZZ_SLOW = {other:?}: expected \"report\" or \"fail\""),
    };
    // A run stopped by the test unwinds with a `Stop`: that is not a panic to report, so
    // the hook stays quiet for it (and only for it).
    let default_hook = std::panic::take_hook();
    std::panic::set_hook(Box::new(move |info| {
        if !info.payload().is::<Stop>() {
            default_hook(info);
        }
    }));
    let originals: Vec<Original> = scene_files()
        .into_iter()
        .map(|path| {
            // One broken scene is not UTF-8 on purpose: its text is read leniently.
            let text =
                String::from_utf8_lossy(&std::fs::read(&path).expect("a scene file")).into_owned();
            let scene = Scene::from_text(&path, &text).ok();
            let size = scene.as_ref().map_or(1.0, size);
            let run_time = scene.and_then(|scene| measure(scene, SMALL_RUN));
            Original {
                path,
                text,
                run_time,
                size,
            }
        })
        .collect();
    assert!(originals.len() >= 30, "expected every shipped scene");
    let small = originals.iter().filter(|o| o.run_time.is_some()).count();
    assert!(small >= 10, "expected small scenes to run, found {small}");
    // Which scenes are small is measured, so it depends on the machine's load (a scene
    // near the limit may fall either side): the list is printed with the run.
    let names: Vec<String> = originals
        .iter()
        .filter(|o| o.run_time.is_some())
        .filter_map(|o| o.path.file_stem().map(|s| s.to_string_lossy().into_owned()))
        .collect();
    println!(
        "{} scenes, {small} small enough to run their mutants: {}",
        originals.len(),
        names.join(", ")
    );

    let mut cases = Cases(seed.max(1));
    let (mut valid, mut located_errors, mut runs, mut on_pace) = (0, 0, 0, 0);
    let mut failures = Vec::new();
    let mut slow = Vec::new();
    let start = Instant::now();
    for case in 0..count {
        if case > 0 && case % 10_000 == 0 {
            println!(
                "{case} cases in {:.1} s: {located_errors} located errors, {valid} validated \
                 ({runs} run), {} failures, {} over pace",
                start.elapsed().as_secs_f64(),
                failures.len(),
                slow.len()
            );
        }
        let original = &originals[cases.below(originals.len())];
        let (mutation, bytes) = mutate(&original.text, &mut cases);
        let what = format!(
            "case {case} (seed {seed:#x}): {} {mutation:?}",
            original.path.display()
        );
        let path = original.path.clone();
        let loaded = within(VALIDATE_LIMIT, move || {
            load(&path, bytes).map(|scene| {
                let path = scene.path.clone();
                (scene, path)
            })
        });
        let scene = match loaded {
            None => {
                failures.push(format!("{what}: reading took over {VALIDATE_LIMIT:?}"));
                break;
            }
            Some(Err(panic)) => {
                failures.push(format!("{what}: panicked reading: {panic}"));
                continue;
            }
            Some(Ok(Err(e))) => {
                if located(&e) {
                    located_errors += 1;
                } else {
                    failures.push(format!("{what}: error without a location: {e}"));
                }
                continue;
            }
            Some(Ok(Ok((scene, _)))) => scene,
        };
        valid += 1;
        let Some((base, pace)) = original.run_time.clone().filter(|_| runs < max_runs) else {
            continue;
        };
        // A mutant may ask for more work than its original (a digit flipped), within
        // the limits: more steps, or larger steps (`size`). It runs at most twenty times
        // the original's time and two seconds, times its growth in size (up to
        // `MAX_BUDGET`), and is judged by its pace (`run_paced`).
        let growth = (size(&scene) / original.size).max(1.0);
        let budget = (base * 20 + Duration::from_secs(2))
            .mul_f64(growth)
            .min(MAX_BUDGET.max(base * 20 + Duration::from_secs(2)));
        runs += 1;
        match run_paced(scene, pace, growth, budget) {
            None => {
                failures.push(format!("{what}: the run did not stop"));
                break;
            }
            Some(Err(e)) if e == ON_PACE => on_pace += 1,
            Some(Err(e)) if e.starts_with(OVER_PACE) => {
                if report_slow {
                    // Printed as found too, so a deep run stopped early still lists them.
                    println!("over pace, reported: {what}: the run was {e}");
                    slow.push(format!("{what}: the run was {e}"));
                } else {
                    failures.push(format!("{what}: the run was {e}"));
                }
            }
            Some(Err(panic)) => failures.push(format!("{what}: panicked running: {panic}")),
            Some(Ok(())) => {}
        }
    }
    // The loop stops early at a case that does not stop: the cases covered are those.
    let covered = located_errors + valid;
    println!(
        "{covered} of {count} cases from seed {seed:#x} in {:.1} s: {located_errors} located errors, \
         {valid} validated ({runs} run, {on_pace} of them stopped on pace at their time \
         budget), {} failures, {} over pace and reported (SINEW_FUZZ_SLOW=report)",
        start.elapsed().as_secs_f64(),
        failures.len(),
        slow.len()
    );
    for case in &slow {
        println!("over pace (listed again): {case}");
    }
    assert!(failures.is_empty(), "{}", failures.join("\n"));
    assert_eq!(located_errors + valid, count);
}

/// Every broken scene that is meant to fail when it is read and checked (`expect-exit:
/// 2`) does, with an error that says where by the rule the mutants are judged by: a
/// mutation that changes nothing leaves the original's error, so an unlocated one would
/// fail deep runs only when they happen to draw that scene.
#[test]
fn every_broken_scene_fails_to_load_with_a_located_error() {
    let dir = scenes_dir().join("bad");
    let mut located_errors = 0;
    for path in scene_files().into_iter().filter(|p| p.starts_with(&dir)) {
        let bytes = std::fs::read(&path).expect("a scene file");
        let meant_to_fail = String::from_utf8_lossy(&bytes).contains("expect-exit: 2");
        match load(&path, bytes) {
            Err(e) => {
                assert!(
                    located(&e),
                    "{}: error without a location: {e}",
                    path.display()
                );
                located_errors += 1;
            }
            Ok(_) => assert!(!meant_to_fail, "{} was read and checked", path.display()),
        }
    }
    assert!(
        located_errors >= 25,
        "{located_errors} broken scenes failed to load"
    );
}

#[test]
fn number_spans_find_every_literal_and_no_name() {
    let text = "Chain(bones: 7, length: 0.15, root: (-1.5e-3, 2E+4, 1_000), w2: 3)";
    let found: Vec<&str> = number_spans(text)
        .into_iter()
        .map(|(a, b)| &text[a..b])
        .collect();
    assert_eq!(found, ["7", "0.15", "-1.5e-3", "2E+4", "1_000", "3"]);
}

#[test]
fn size_counts_the_cloth_particles_of_every_task() {
    let root = scenes_dir();
    let read = |name: &str, from: &str, to: &str| {
        let path = root.join(name);
        let text = std::fs::read_to_string(&path)
            .unwrap()
            .replacen(from, to, 1);
        size(&Scene::from_text(&path, &text).unwrap())
    };
    assert_eq!(read("cloth-ground.ron", "", ""), 1024.0);
    assert_eq!(read("cloth-ground.ron", "size: 32", "size:732"), 535_824.0);
    // Three grid sheets of 8 x 8 (the shipped short stack).
    assert_eq!(read("cloth-stack.ron", "", ""), 3.0 * 64.0);
    // No cloth: 1.
    assert_eq!(read("ik-flower.ron", "", ""), 1.0);
}
