//! Biovision hierarchy (BVH) files: a skeleton (joint names, parents, offsets and each
//! joint's channel order) and its motion (per frame, the root's translation and every
//! joint's rotation), read by a small hand-written parser.
//!
//! Conventions (docs/io.md): a joint's rotation channels are applied in the order they
//! are listed, as intrinsic rotations, so `CHANNELS 3 Zrotation Xrotation Yrotation` with
//! values `(z, x, y)` in degrees is the local rotation `Rz(z) Rx(x) Ry(y)`. The root's
//! position channels are a translation added to its `OFFSET`; other joints may not have
//! position channels (sinew's joints only rotate). An `End Site` becomes a joint named
//! after its parent with `_End` appended, with no channels, so the last bone of each
//! limb has an end to point at.
//!
//! Forward kinematics of [`Bvh::skeleton`] with a frame's [`BvhFrame::pose`] gives every
//! joint's position relative to the root's translation: [`BvhFrame::joint_positions`] adds
//! it. This matches the file's own composition `M = M_parent T(offset) R(channels)` for
//! every joint.
//!
//! Errors name the line and column (both from 1) and what was expected there; no input
//! makes the parser panic, and nesting depth is bounded by an explicit stack, not the call
//! stack.

use sinew_math::{DQuat, DVec3};
use sinew_skeleton::{GlobalPose, JointDef, Pose, Skeleton, SkeletonError};
use std::fmt;

/// One channel of a BVH joint.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Channel {
    /// Translation along x (root only).
    Xposition,
    /// Translation along y (root only).
    Yposition,
    /// Translation along z (root only).
    Zposition,
    /// Rotation about x, in degrees.
    Xrotation,
    /// Rotation about y, in degrees.
    Yrotation,
    /// Rotation about z, in degrees.
    Zrotation,
}

impl Channel {
    fn parse(word: &str) -> Option<Self> {
        Some(match word {
            "Xposition" => Self::Xposition,
            "Yposition" => Self::Yposition,
            "Zposition" => Self::Zposition,
            "Xrotation" => Self::Xrotation,
            "Yrotation" => Self::Yrotation,
            "Zrotation" => Self::Zrotation,
            _ => return None,
        })
    }

    fn is_position(self) -> bool {
        matches!(self, Self::Xposition | Self::Yposition | Self::Zposition)
    }
}

/// A located error in a BVH file.
#[derive(Clone, Debug, PartialEq)]
pub struct BvhError {
    /// The line, from 1.
    pub line: usize,
    /// The column (in characters), from 1.
    pub column: usize,
    /// What was expected and what was found, or what is wrong.
    pub message: String,
}

impl fmt::Display for BvhError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "line {}, column {}: {}",
            self.line, self.column, self.message
        )
    }
}

impl std::error::Error for BvhError {}

/// One frame of motion.
#[derive(Clone, Debug, PartialEq)]
pub struct BvhFrame {
    /// The root's position channels (zero where the root has none), added to its offset.
    pub root_translation: DVec3,
    /// Every joint's local rotation (the identity for end sites).
    pub pose: Pose,
}

impl BvhFrame {
    /// Every joint's position at this frame: forward kinematics of the pose, shifted by
    /// the root's translation. An error when `skeleton` is not the one the frame was read
    /// with (a different joint count).
    pub fn joint_positions(&self, skeleton: &Skeleton) -> Result<Vec<DVec3>, SkeletonError> {
        let mut global = GlobalPose::new();
        skeleton.forward_kinematics(&self.pose, &mut global)?;
        Ok(global
            .positions
            .iter()
            .map(|p| *p + self.root_translation)
            .collect())
    }
}

/// A BVH file's skeleton and motion.
#[derive(Clone, Debug, PartialEq)]
pub struct Bvh {
    /// The joints in file order (end sites included), named, with their offsets.
    pub skeleton: Skeleton,
    /// Each joint's channels in file order (empty for end sites).
    pub channels: Vec<Vec<Channel>>,
    /// Seconds per frame.
    pub frame_time: f64,
    /// The frames.
    pub frames: Vec<BvhFrame>,
}

impl Bvh {
    /// The number of values on each frame line (the sum of the joints' channel counts).
    #[must_use]
    pub fn channel_count(&self) -> usize {
        self.channels.iter().map(Vec::len).sum()
    }
}

/// A token with its position.
#[derive(Clone, Copy, Debug)]
struct Token<'a> {
    text: &'a str,
    line: usize,
    column: usize,
}

/// The file split into lines of tokens; braces are tokens of their own even when written
/// against a word.
fn tokenize(text: &str) -> Vec<Vec<Token<'_>>> {
    let mut lines = Vec::new();
    for (l, line) in text.lines().enumerate() {
        let mut tokens = Vec::new();
        let mut start: Option<(usize, usize)> = None; // (byte, column)
        let mut column = 0;
        for (byte, ch) in line.char_indices() {
            column += 1;
            let brace = ch == '{' || ch == '}';
            if ch.is_whitespace() || brace {
                if let Some((b, c)) = start.take() {
                    tokens.push(Token {
                        text: &line[b..byte],
                        line: l + 1,
                        column: c,
                    });
                }
                if brace {
                    tokens.push(Token {
                        text: &line[byte..byte + 1],
                        line: l + 1,
                        column,
                    });
                }
            } else if start.is_none() {
                start = Some((byte, column));
            }
        }
        if let Some((b, c)) = start {
            tokens.push(Token {
                text: &line[b..],
                line: l + 1,
                column: c,
            });
        }
        lines.push(tokens);
    }
    lines
}

/// A cursor over the tokens of the hierarchy section.
struct Cursor<'a> {
    lines: Vec<Vec<Token<'a>>>,
    line: usize,
    index: usize,
    /// Where the file ends, for "found the end of the file" errors.
    end: (usize, usize),
}

impl<'a> Cursor<'a> {
    fn new(text: &'a str) -> Self {
        let lines = tokenize(text);
        let last = text.lines().count().max(1);
        let end_col = text.lines().last().map_or(1, |l| l.chars().count() + 1);
        Self {
            lines,
            line: 0,
            index: 0,
            end: (last, end_col),
        }
    }

    fn peek(&mut self) -> Option<Token<'a>> {
        while self.line < self.lines.len() {
            if let Some(t) = self.lines[self.line].get(self.index) {
                return Some(*t);
            }
            self.line += 1;
            self.index = 0;
        }
        None
    }

    fn next(&mut self, expected: &str) -> Result<Token<'a>, BvhError> {
        match self.peek() {
            Some(t) => {
                self.index += 1;
                Ok(t)
            }
            None => Err(BvhError {
                line: self.end.0,
                column: self.end.1,
                message: format!("expected {expected}, found the end of the file"),
            }),
        }
    }

    fn keyword(&mut self, word: &str) -> Result<Token<'a>, BvhError> {
        let t = self.next(&format!("`{word}`"))?;
        if t.text == word {
            Ok(t)
        } else {
            Err(unexpected(&t, &format!("`{word}`")))
        }
    }

    fn number(&mut self, what: &str) -> Result<f64, BvhError> {
        let t = self.next(what)?;
        parse_number(&t, what)
    }

    /// The tokens of the current line from the cursor on, moving to the next line.
    fn rest_of_line(&mut self) -> Vec<Token<'a>> {
        let rest = self
            .lines
            .get(self.line)
            .and_then(|l| l.get(self.index..))
            .map(<[Token<'a>]>::to_vec)
            .unwrap_or_default();
        self.line += 1;
        self.index = 0;
        rest
    }
}

fn unexpected(t: &Token<'_>, expected: &str) -> BvhError {
    BvhError {
        line: t.line,
        column: t.column,
        message: format!("expected {expected}, found `{}`", t.text),
    }
}

fn parse_number(t: &Token<'_>, what: &str) -> Result<f64, BvhError> {
    match t.text.parse::<f64>() {
        Ok(v) if v.is_finite() => Ok(v),
        _ => Err(unexpected(t, &format!("a finite number ({what})"))),
    }
}

/// The largest channel count a joint may declare (six: three positions, three rotations,
/// with room for files that repeat an axis).
const MAX_CHANNELS: usize = 9;

/// Reads a BVH file from its text.
///
/// # Example
///
/// A malformed number is an error naming its line and column.
///
/// ```
/// use sinew_io::parse_bvh;
///
/// let err = parse_bvh("HIERARCHY\nROOT Hips\n{\n  OFFSET 0 zero 0\n").unwrap_err();
/// assert_eq!((err.line, err.column), (4, 12));
/// assert!(err.message.contains("`zero`"), "{err}");
/// ```
pub fn parse_bvh(text: &str) -> Result<Bvh, BvhError> {
    let mut cur = Cursor::new(text);
    cur.keyword("HIERARCHY")?;
    cur.keyword("ROOT")?;
    let mut joints: Vec<JointDef> = Vec::new();
    let mut channels: Vec<Vec<Channel>> = Vec::new();
    // The joints whose `{ ... }` is open, innermost last.
    let mut open: Vec<usize> = Vec::new();
    // The next joint's parent and kind: (parent, is end site, name token).
    let mut pending: Option<(Option<usize>, bool, Token<'_>)> =
        Some((None, false, cur.next("the root joint's name")?));
    loop {
        if let Some((parent, end_site, name)) = pending.take() {
            let joint = joints.len();
            let label = if end_site {
                // The parent is open, so it exists.
                let parent_name = parent
                    .and_then(|p| joints.get(p))
                    .and_then(|j| j.name.clone())
                    .unwrap_or_default();
                format!("{parent_name}_End")
            } else {
                name.text.to_string()
            };
            if !end_site && (name.text == "{" || name.text == "}") {
                return Err(unexpected(&name, "a joint name"));
            }
            cur.keyword("{")?;
            cur.keyword("OFFSET")?;
            let x = cur.number("OFFSET's x")?;
            let y = cur.number("OFFSET's y")?;
            let z = cur.number("OFFSET's z")?;
            let mut list = Vec::new();
            if !end_site {
                cur.keyword("CHANNELS")?;
                let count_token = cur.next("the channel count")?;
                let count = match count_token.text.parse::<usize>() {
                    Ok(n) if n <= MAX_CHANNELS => n,
                    _ => {
                        return Err(unexpected(
                            &count_token,
                            &format!("a channel count from 0 to {MAX_CHANNELS}"),
                        ));
                    }
                };
                for _ in 0..count {
                    let t = cur.next("a channel name")?;
                    let Some(c) = Channel::parse(t.text) else {
                        return Err(unexpected(
                            &t,
                            "a channel name (Xposition, Yposition, Zposition, Xrotation, Yrotation, Zrotation)",
                        ));
                    };
                    if c.is_position() && parent.is_some() {
                        return Err(BvhError {
                            line: t.line,
                            column: t.column,
                            message: format!(
                                "joint `{label}`: position channels are allowed on the root only (sinew's joints only rotate)"
                            ),
                        });
                    }
                    list.push(c);
                }
            }
            joints.push(JointDef {
                name: Some(label),
                parent,
                offset: DVec3::new(x, y, z),
                ..JointDef::default()
            });
            channels.push(list);
            open.push(joint);
            if end_site {
                cur.keyword("}")?;
                open.pop();
            }
        }
        let Some(&current) = open.last() else {
            break;
        };
        let t = cur.next("`JOINT`, `End Site` or `}`")?;
        match t.text {
            "JOINT" => pending = Some((Some(current), false, cur.next("a joint name")?)),
            "End" => {
                cur.keyword("Site")?;
                pending = Some((Some(current), true, t));
            }
            "}" => {
                open.pop();
            }
            _ => return Err(unexpected(&t, "`JOINT`, `End Site` or `}`")),
        }
    }
    let skeleton = Skeleton::new(joints).map_err(|e| BvhError {
        line: 1,
        column: 1,
        message: format!("the hierarchy is not a valid skeleton: {e}"),
    })?;

    let motion = cur.next("`MOTION`")?;
    if motion.text != "MOTION" {
        let expected = if motion.text == "ROOT" {
            "`MOTION` (only one ROOT per file is supported)"
        } else {
            "`MOTION`"
        };
        return Err(unexpected(&motion, expected));
    }
    let frames_token = cur.keyword("Frames:")?;
    let count_token = cur.next("the frame count")?;
    let frame_count = count_token
        .text
        .parse::<usize>()
        .map_err(|_| unexpected(&count_token, "a whole number of frames"))?;
    cur.keyword("Frame")?;
    cur.keyword("Time:")?;
    let time_token = cur.next("the frame time")?;
    let frame_time = parse_number(&time_token, "the frame time in seconds")?;
    if frame_time <= 0.0 {
        return Err(unexpected(&time_token, "a positive frame time"));
    }
    // Nothing else may follow on the frame time's line.
    if let Some(extra) = cur.rest_of_line().first() {
        return Err(unexpected(
            extra,
            "the end of the line after the frame time",
        ));
    }

    let values_per_frame: usize = channels.iter().map(Vec::len).sum();
    let mut frames = Vec::new();
    while let Some(first) = cur.peek() {
        let line = cur.rest_of_line();
        if frames.len() == frame_count {
            return Err(unexpected(
                &first,
                &format!("the end of the file after {frame_count} frames"),
            ));
        }
        if line.len() != values_per_frame {
            return Err(BvhError {
                line: first.line,
                column: first.column,
                message: format!(
                    "expected {values_per_frame} values on frame {}, found {}",
                    frames.len(),
                    line.len()
                ),
            });
        }
        let mut values = line.iter();
        let mut root_translation = DVec3::ZERO;
        let mut rotations = Vec::with_capacity(channels.len());
        for (j, list) in channels.iter().enumerate() {
            let mut rotation = DQuat::IDENTITY;
            for c in list {
                // The line has exactly one value per channel (checked above).
                let Some(t) = values.next() else {
                    return Err(unexpected(&first, "a value per channel"));
                };
                let name = skeleton.name(j).unwrap_or("?");
                let v = parse_number(t, &format!("channel {c:?} of joint `{name}`"))?;
                match c {
                    Channel::Xposition => root_translation.x = v,
                    Channel::Yposition => root_translation.y = v,
                    Channel::Zposition => root_translation.z = v,
                    Channel::Xrotation => rotation *= DQuat::from_rotation_x(v.to_radians()),
                    Channel::Yrotation => rotation *= DQuat::from_rotation_y(v.to_radians()),
                    Channel::Zrotation => rotation *= DQuat::from_rotation_z(v.to_radians()),
                }
            }
            rotations.push(rotation.normalize());
        }
        frames.push(BvhFrame {
            root_translation,
            pose: Pose { rotations },
        });
    }
    if frames.len() != frame_count {
        return Err(BvhError {
            line: frames_token.line,
            column: frames_token.column,
            message: format!(
                "the file declares {frame_count} frames but has {}",
                frames.len()
            ),
        });
    }
    Ok(Bvh {
        skeleton,
        channels,
        frame_time,
        frames,
    })
}
