//! Scene files cannot crash the runner: every shipped scene (`scenes/`, `scenes/long/`,
//! `scenes/bad/`) is mutated (bytes flipped, the file cut short, lines swapped or
//! duplicated, numbers made huge, tiny, NaN or infinite in every spelling RON accepts,
//! brackets nested deeply) and each mutant is read and checked. The property: a located
//! error (file:line:col, or the task and the field) or a scene that validates, never a
//! panic, and never longer than a time limit. The mutants of the small scenes that
//! validate are also run, each under a time limit scaled from its original's run.
//!
//! Cases come from a fixed seed, so CI sees the same ones every time;
//! `SINEW_FUZZ_CASES` sets how many (default 300), `SINEW_FUZZ_SEED` the seed and
//! `SINEW_FUZZ_RUNS` the most mutants run (default: every one that validates of a small
//! scene; 0 for a deep run of reading and checking alone). The deep run's count, time
//! and result are in docs/labcheck.md ("Runs").

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
/// panicked.
fn within<T: Send + 'static>(
    limit: Duration,
    f: impl FnOnce() -> T + Send + 'static,
) -> Option<Result<T, String>> {
    let (send, receive) = mpsc::channel();
    std::thread::Builder::new()
        .name("fuzz case".into())
        .spawn(move || {
            let outcome = std::panic::catch_unwind(std::panic::AssertUnwindSafe(f)).map_err(|p| {
                if p.is::<OverTime>() {
                    // Stopped at its time limit: reported as such, not as a panic.
                    return OVER_TIME.to_string();
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

/// The payload of the panic that stops a run over its time limit (from the progress
/// callback, so a run that goes on too long stops instead of running on in the
/// background).
struct OverTime;

/// What [`within`] reports for a run stopped by [`OverTime`].
const OVER_TIME: &str = "over the time limit";

/// Runs `scene` on its own thread: `Some(Ok(()))` when it finished within `limit`,
/// `Some(Err(OVER_TIME))` when it was stopped at the first unit of work after `limit`,
/// `Some(Err(message))` when it panicked, `None` when it did not even stop (a unit of
/// work that never ends).
fn run_within(scene: Scene, limit: Duration) -> Option<Result<(), String>> {
    within(limit * 2 + Duration::from_secs(10), move || {
        let start = Instant::now();
        let stop = move |_: &str, _: usize, _: usize| {
            if start.elapsed() > limit {
                std::panic::panic_any(OverTime);
            }
        };
        let _ = scene.run(&RunOptions {
            progress: Some(&stop),
            ..RunOptions::default()
        });
    })
}

/// Reads mutated bytes as the runner does: invalid UTF-8 is a located error too.
fn load(path: &Path, bytes: Vec<u8>) -> Result<Scene, SceneError> {
    Scene::from_bytes(path, &bytes)
}

fn scene_files() -> Vec<PathBuf> {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../scenes");
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
/// unmutated run took.
struct Original {
    path: PathBuf,
    text: String,
    run_time: Option<Duration>,
}

#[test]
fn mutated_scenes_give_a_located_error_or_validate_and_run_in_bounded_time() {
    let count: usize = env_or("SINEW_FUZZ_CASES", DEFAULT_CASES);
    let seed: u64 = env_or("SINEW_FUZZ_SEED", DEFAULT_SEED);
    let max_runs: usize = env_or("SINEW_FUZZ_RUNS", usize::MAX);
    // A run stopped at its time limit unwinds with `OverTime`: that is not a panic to
    // report, so the hook stays quiet for it (and only for it).
    let default_hook = std::panic::take_hook();
    std::panic::set_hook(Box::new(move |info| {
        if !info.payload().is::<OverTime>() {
            default_hook(info);
        }
    }));
    let originals: Vec<Original> = scene_files()
        .into_iter()
        .map(|path| {
            // One broken scene is not UTF-8 on purpose: its text is read leniently.
            let text =
                String::from_utf8_lossy(&std::fs::read(&path).expect("a scene file")).into_owned();
            let run_time = Scene::from_text(&path, &text).ok().and_then(|scene| {
                let start = Instant::now();
                match run_within(scene, SMALL_RUN) {
                    Some(Ok(())) => Some(start.elapsed()),
                    _ => None,
                }
            });
            Original {
                path,
                text,
                run_time,
            }
        })
        .collect();
    assert!(originals.len() >= 30, "expected every shipped scene");
    let small = originals.iter().filter(|o| o.run_time.is_some()).count();
    assert!(small >= 10, "expected small scenes to run, found {small}");
    println!(
        "{} scenes, {small} small enough to run their mutants",
        originals.len()
    );

    let mut cases = Cases(seed.max(1));
    let (mut valid, mut located_errors, mut runs) = (0, 0, 0);
    let mut failures = Vec::new();
    let start = Instant::now();
    for case in 0..count {
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
        let Some(base) = original.run_time.filter(|_| runs < max_runs) else {
            continue;
        };
        // A mutant may ask for more work than its original (a digit flipped), within
        // the limits; twenty times the original's time and two seconds allow for that
        // and for a loaded machine.
        let limit = base * 20 + Duration::from_secs(2);
        runs += 1;
        match run_within(scene, limit) {
            None => {
                failures.push(format!("{what}: the run did not stop"));
                break;
            }
            Some(Err(e)) if e == OVER_TIME => {
                failures.push(format!("{what}: the run took over {limit:?}"));
            }
            Some(Err(panic)) => failures.push(format!("{what}: panicked running: {panic}")),
            Some(Ok(())) => {}
        }
    }
    println!(
        "{count} cases from seed {seed:#x} in {:.1} s: {located_errors} located errors, \
         {valid} validated ({runs} run), {} failures",
        start.elapsed().as_secs_f64(),
        failures.len()
    );
    assert!(failures.is_empty(), "{}", failures.join("\n"));
    assert_eq!(located_errors + valid, count);
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
