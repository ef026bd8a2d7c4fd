//! Camera paths: an animation's frames, each the settings of one view. Keyframes (eye, look-at,
//! field of view) are passed through smoothly: Catmull–Rom splines through the eyes, the
//! look-at points and the fields of view over one knot sequence, centripetal in how far the
//! camera moves ([`knots`]: no cusp or loop where keys bunch up), the frames evenly spaced in
//! it, so that the camera's velocity is continuous through every key. The first and last frames
//! are the first and last keys, exactly. The orbit is `Scene::turntable`'s (`Animation::Orbit`).

use glam::DVec3;

use crate::scene::Scene;
use crate::settings::{Settings, SettingsError};

/// A view the camera passes through: where it stands, where it looks, its vertical field of
/// view in degrees.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Keyframe {
    pub eye: DVec3,
    pub look_at: DVec3,
    pub fov: f32,
}

/// An animation: `frames` views along keyframes, or round the view the settings give.
#[derive(Clone, Debug, PartialEq)]
pub enum Animation {
    /// Along a camera path through its keyframes (at least two).
    Path { keys: Vec<Keyframe>, frames: u32 },
    /// A turntable: the view turned about the up axis by 360°/frames a frame (`Scene::turntable`).
    Orbit { frames: u32 },
}

impl Animation {
    /// A path through `keys` of `frames` frames, checked: two keys or more, each finite with its
    /// eye off its look-at point and a field of view between 0 and 180 degrees.
    pub fn path(keys: Vec<Keyframe>, frames: u32) -> Result<Self, SettingsError> {
        let wrong = |problem: String| Err(SettingsError::new("keyframe", problem));
        if keys.len() < 2 {
            return wrong(format!("a camera path needs two keyframes or more, not {}", keys.len()));
        }
        // Counted from 1, as a file's tables are.
        for (i, k) in (1..).zip(&keys) {
            if !(k.eye.is_finite() && k.look_at.is_finite()) || k.eye == k.look_at {
                return wrong(format!("{i}: eye and look_at must be finite and apart"));
            }
            if !(k.fov > 0.0 && k.fov < 180.0) {
                return wrong(format!("{i}: fov must be between 0 and 180 degrees"));
            }
        }
        Self::check_frames(frames)?;
        Ok(Self::Path { keys, frames })
    }

    /// A turntable of `frames` frames.
    pub fn orbit(frames: u32) -> Result<Self, SettingsError> {
        Self::check_frames(frames)?;
        Ok(Self::Orbit { frames })
    }

    fn check_frames(frames: u32) -> Result<(), SettingsError> {
        match frames {
            1..=MAX_FRAMES => Ok(()),
            _ => Err(SettingsError::new("frames", format!("must be between 1 and {MAX_FRAMES}"))),
        }
    }

    pub fn frames(&self) -> u32 {
        match self {
            Self::Path { frames, .. } | Self::Orbit { frames } => *frames,
        }
    }

    /// Frame `k`'s settings: `settings` with the camera of that frame (`k` below
    /// [`Self::frames`]).
    pub fn frame(&self, scene: &Scene, settings: &Settings, k: u32) -> Settings {
        assert!(k < self.frames(), "frame {k} of {}", self.frames());
        match self {
            Self::Orbit { frames } => scene.turned(settings, k, *frames),
            Self::Path { keys, frames } => {
                let s = if *frames == 1 { 0.0 } else { f64::from(k) / f64::from(frames - 1) };
                let view = along(keys, s);
                Settings { eye: Some(view.eye), look_at: Some(view.look_at), fov: view.fov, ..settings.clone() }
            }
        }
    }
}

/// The most frames an animation has (a day at 60 frames a second, past any fly-through).
pub const MAX_FRAMES: u32 = 5_184_000;

/// The camera `s` ∈ [0, 1] along the path through `keys` (two or more): `s` is the share of the
/// path's knot parameter ([`knots`]), in which the path moves with a continuous velocity.
pub fn along(keys: &[Keyframe], s: f64) -> Keyframe {
    let n = keys.len();
    let knots = knots(keys);
    let t = s.clamp(0.0, 1.0) * knots[n - 1];
    let i = knots[1..n - 1].partition_point(|&k| k <= t);
    if t == knots[i] || t >= knots[n - 1] {
        return keys[if t >= knots[n - 1] { n - 1 } else { i }];
    }
    // The four keys about stretch i, and their knots, the ends continued straight on.
    let at = |j: isize| j.clamp(0, n as isize - 1) as usize;
    let quad = |j: isize| [j - 1, j, j + 1, j + 2].map(at);
    let [a, b, c, d] = quad(i as isize);
    let first = i == 0;
    let last = i + 2 == n;
    let tk = [
        if first { 2.0 * knots[0] - knots[1] } else { knots[a] },
        knots[b],
        knots[c],
        if last { 2.0 * knots[n - 1] - knots[n - 2] } else { knots[d] },
    ];
    let ends = |f: &dyn Fn(&Keyframe) -> DVec3| {
        let p0 = if first { 2.0 * f(&keys[0]) - f(&keys[1]) } else { f(&keys[a]) };
        let p3 = if last { 2.0 * f(&keys[n - 1]) - f(&keys[n - 2]) } else { f(&keys[d]) };
        [p0, f(&keys[b]), f(&keys[c]), p3]
    };
    let fov = |k: &Keyframe| DVec3::splat(f64::from(k.fov));
    let eye = barry_goldman(ends(&|k| k.eye), tk, t);
    let look_at = barry_goldman(ends(&|k| k.look_at), tk, t);
    let fov = barry_goldman(ends(&fov), tk, t).x.clamp(1e-3, 180.0 - 1e-3);
    Keyframe { eye, look_at, fov: fov as f32 }
}

/// The keys' knots: 0 at the first, then each stretch the square root of how far the view
/// moves along it (centripetal: a path with no cusp or loop where keys bunch up): the eye's
/// and the look-at point's distances, and the field of view's change as the arc it sweeps at
/// the distance looked at. A key repeated takes no time (a millionth of the longest stretch,
/// for the arithmetic); one each if nothing moves.
pub fn knots(keys: &[Keyframe]) -> Vec<f64> {
    let moved = |a: &Keyframe, b: &Keyframe| {
        let reach = 0.5 * (a.eye.distance(a.look_at) + b.eye.distance(b.look_at));
        let zoom = f64::from(a.fov - b.fov).to_radians().abs() * reach;
        (a.eye.distance(b.eye) + a.look_at.distance(b.look_at) + zoom).sqrt()
    };
    let steps: Vec<f64> = keys.windows(2).map(|w| moved(&w[0], &w[1])).collect();
    let longest = steps.iter().copied().fold(0.0, f64::max);
    let mut knots = vec![0.0];
    for step in steps {
        let step = if longest > 0.0 { step.max(1e-6 * longest) } else { 1.0 };
        knots.push(knots[knots.len() - 1] + step);
    }
    knots
}

/// The Catmull–Rom spline through `p[1]` (at knot `t[1]`) and `p[2]` (at `t[2]`), its
/// neighbours `p[0]` and `p[3]` at `t[0]` and `t[3]`, at `u` between `t[1]` and `t[2]` (Barry and
/// Goldman's pyramid of linear interpolations).
fn barry_goldman(p: [DVec3; 4], t: [f64; 4], u: f64) -> DVec3 {
    let lerp = |a: DVec3, b: DVec3, ta: f64, tb: f64| a + (b - a) * ((u - ta) / (tb - ta));
    let a1 = lerp(p[0], p[1], t[0], t[1]);
    let a2 = lerp(p[1], p[2], t[1], t[2]);
    let a3 = lerp(p[2], p[3], t[2], t[3]);
    let b1 = lerp(a1, a2, t[0], t[2]);
    let b2 = lerp(a2, a3, t[1], t[3]);
    lerp(b1, b2, t[1], t[2])
}

#[cfg(test)]
mod tests {
    use super::*;

    fn key(eye: [f64; 3], fov: f32) -> Keyframe {
        Keyframe { eye: DVec3::from(eye), look_at: DVec3::ZERO, fov }
    }

    #[test]
    fn a_path_passes_through_its_keys_smoothly() {
        let keys = vec![key([5.0, 0.0, 0.0], 40.0), key([0.0, 1.0, 5.0], 30.0), key([-5.0, 0.0, 0.2], 50.0)];
        let knots = knots(&keys);
        for (i, k) in keys.iter().enumerate() {
            let at = along(&keys, knots[i] / knots[2]);
            assert!(at.eye.distance(k.eye) < 1e-12 && (at.fov - k.fov).abs() < 1e-5, "key {i}: {at:?}");
        }
        assert_eq!((along(&keys, 0.0), along(&keys, 1.0)), (keys[0], keys[2]), "the ends exactly");
        // Its velocity continuous through the middle key: the difference quotients either side agree.
        let h = 1e-7;
        let middle = knots[1] / knots[2];
        assert!(along(&keys, middle).eye.distance(keys[1].eye) < 1e-12);
        let before = (along(&keys, middle).eye - along(&keys, middle - h).eye) / h;
        let after = (along(&keys, middle + h).eye - along(&keys, middle).eye) / h;
        assert!(before.distance(after) < 1e-3 * before.length(), "{before} vs {after}");
        // Bunched keys make no loop: the path stays between them.
        let bunched = vec![key([0.0, 0.0, 0.0], 40.0), key([1.0, 0.0, 0.0], 40.0), key([1.001, 0.0, 0.0], 40.0)];
        let furthest = (0..=100).map(|s| along(&bunched, s as f64 / 100.0).eye.x).fold(f64::MIN, f64::max);
        assert!(furthest <= 1.001 + 1e-9, "{furthest}");
    }

    #[test]
    fn two_keys_are_a_straight_line_and_repeated_keys_a_standstill() {
        let keys = vec![key([0.0, 0.0, 4.0], 20.0), key([2.0, 0.0, 4.0], 60.0)];
        for s in [0.0, 0.25, 0.5, 1.0] {
            let at = along(&keys, s);
            assert!(at.eye.distance(DVec3::new(2.0 * s, 0.0, 4.0)) < 1e-12, "{s}: {at:?}");
            assert!((at.fov - (20.0 + 40.0 * s as f32)).abs() < 1e-4, "{s}: {}", at.fov);
        }
        let still = vec![key([1.0, 2.0, 3.0], 40.0); 3];
        assert_eq!(along(&still, 0.3).eye, DVec3::new(1.0, 2.0, 3.0));
        // A zoom alone takes time: half way, half the change.
        let zoom = vec![key([1.0, 2.0, 3.0], 20.0), key([1.0, 2.0, 3.0], 60.0)];
        assert!((along(&zoom, 0.5).fov - 40.0).abs() < 1e-4);
    }

    #[test]
    fn bad_paths_are_named() {
        let one = Animation::path(vec![key([1.0, 0.0, 0.0], 40.0)], 10).unwrap_err();
        assert_eq!(one.to_string(), "keyframe a camera path needs two keyframes or more, not 1");
        let at_eye = Animation::path(vec![key([1.0, 0.0, 0.0], 40.0), key([0.0, 0.0, 0.0], 40.0)], 10);
        assert_eq!(at_eye.unwrap_err().to_string(), "keyframe 2: eye and look_at must be finite and apart");
        let wide = Animation::path(vec![key([1.0, 0.0, 0.0], 40.0), key([2.0, 0.0, 0.0], 180.0)], 10);
        assert!(wide.unwrap_err().problem.contains("2: fov"));
        assert_eq!(Animation::orbit(0).unwrap_err().option, "frames");
    }
}
