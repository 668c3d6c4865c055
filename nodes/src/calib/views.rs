//! Which photo is which view: photos are numbered by the last number in their
//! file name (`left_07.png`, `left07.jpg`, `IMG_0007.JPG`: view 7), so that a
//! stereo pair is the left and right photo of one number, whatever other files
//! the folder holds and whichever photos are missing or refused.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use super::{BoardView, Refusal};

/// File extensions read as images (case-insensitive).
pub const IMAGE_EXTENSIONS: [&str; 3] = ["png", "jpg", "jpeg"];

/// The view number of a photo: the last run of digits in its file name
/// before the extension (`left_07.png` -> 7, `cam2_shot0042.jpg` -> 42).
pub fn view_number(file_name: &str) -> Option<u32> {
    let stem = Path::new(file_name).file_stem()?.to_str()?;
    let end = stem.rfind(|c: char| c.is_ascii_digit())? + 1;
    let start = stem[..end]
        .rfind(|c: char| !c.is_ascii_digit())
        .map_or(0, |i| i + 1);
    stem[start..end].parse().ok()
}

/// Photos of a folder by view number, and what was left out and why.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct NumberedPhotos {
    /// View number -> file.
    pub files: BTreeMap<u32, PathBuf>,
    /// Files the glob matched that are not used, each with the reason.
    pub skipped: Vec<String>,
}

/// The image files of `dir` whose names match `glob`, numbered by
/// [`view_number`]. Files that are not images by their extension, or have no
/// number in their name, are skipped (and listed); two photos with one number
/// are an error naming both, since either could be the view.
pub fn numbered_photos(dir: &Path, glob: &glob::Pattern) -> Result<NumberedPhotos, String> {
    let entries = std::fs::read_dir(dir).map_err(|e| format!("{}: {e}", dir.display()))?;
    let mut names: Vec<(String, PathBuf)> = entries
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.is_file())
        .filter_map(|p| Some((p.file_name()?.to_string_lossy().into_owned(), p)))
        .filter(|(n, _)| glob.matches(n))
        .collect();
    names.sort();
    let mut out = NumberedPhotos::default();
    for (name, path) in names {
        let ext = path
            .extension()
            .map(|e| e.to_string_lossy().to_lowercase())
            .unwrap_or_default();
        if !IMAGE_EXTENSIONS.contains(&ext.as_str()) {
            out.skipped.push(format!(
                "{name}: skipped: not an image (reads {})",
                IMAGE_EXTENSIONS.join(", ")
            ));
            continue;
        }
        let Some(n) = view_number(&name) else {
            out.skipped.push(format!(
                "{name}: skipped: no number in its name to tell which view it is"
            ));
            continue;
        };
        if let Some(other) = out.files.insert(n, path) {
            let other = other.file_name().unwrap_or_default().to_string_lossy();
            return Err(format!(
                "{}: {other} and {name} both number view {n}; rename one or narrow the glob",
                dir.display()
            ));
        }
    }
    if out.files.is_empty() {
        let why = if out.skipped.is_empty() {
            String::new()
        } else {
            format!(" ({})", out.skipped.join("; "))
        };
        return Err(format!(
            "{}: no image matches {:?}{why}",
            dir.display(),
            glob.as_str()
        ));
    }
    Ok(out)
}

/// What one camera's detection made of one photo.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PhotoRecord {
    /// 0 when the board was found, 1 when the photo could not be read, else
    /// the [`Refusal::code`] of why the board was refused.
    pub refusal: u8,
    /// Image width and height, px (0 x 0 when it could not be read).
    pub size: (usize, usize),
}

impl PhotoRecord {
    /// The `refusal` of a photo whose board was found.
    pub const FOUND: u8 = 0;
    /// The `refusal` of a photo that could not be read.
    pub const UNREADABLE: u8 = 1;

    /// Whether the board was found.
    pub fn found(&self) -> bool {
        self.refusal == Self::FOUND
    }
}

/// One side of a stereo calibration: its boards by view number and, when
/// known, every photo's record (to tell a refused photo from a missing one).
#[derive(Debug, Clone, Default)]
pub struct Side {
    /// Boards found, with their image size, by view number.
    pub boards: BTreeMap<u32, (BoardView, (usize, usize))>,
    /// Every photo of this side by view number, if known.
    pub photos: Option<BTreeMap<u32, PhotoRecord>>,
}

impl Side {
    /// What became of view `v` on this side, in words.
    fn fate(&self, v: u32) -> String {
        if self.boards.contains_key(&v) {
            return "board found".into();
        }
        match self.photos.as_ref().map(|p| p.get(&v)) {
            Some(Some(r)) if r.refusal == PhotoRecord::UNREADABLE => "photo unreadable".into(),
            Some(Some(r)) => format!("board refused ({})", Refusal::describe_code(r.refusal)),
            Some(None) => "no photo".into(),
            None => "no board (refused or no photo)".into(),
        }
    }

    fn views(&self) -> impl Iterator<Item = u32> + '_ {
        self.boards
            .keys()
            .copied()
            .chain(self.photos.iter().flat_map(|p| p.keys().copied()))
    }
}

/// Stereo pairs by view number, and notes on the views left out.
#[derive(Debug, Clone)]
pub struct Pairing {
    /// View numbers of the pairs, in order.
    pub views: Vec<u32>,
    /// The pairs' boards (left, right).
    pub pairs: Vec<(BoardView, BoardView)>,
    /// Left and right image sizes, px.
    pub sizes: [(usize, usize); 2],
    /// One line per view left out: which side lacks the board, and why.
    pub dropped: Vec<String>,
}

/// Two photos whose corners all lie within this distance show one board pose:
/// a photo copied, or taken twice without moving anything. Real retakes of a
/// held board move by pixels; detection noise is hundredths of one.
pub const SAME_POSE_PX: f64 = 0.5;

/// The largest distance between corresponding corners of two views, px;
/// `None` when they have different corner counts.
pub fn max_corner_shift_px(a: &BoardView, b: &BoardView) -> Option<f64> {
    (a.image_px.len() == b.image_px.len()).then(|| {
        a.image_px
            .iter()
            .zip(&b.image_px)
            .map(|(p, q)| (p - q).norm())
            .fold(0.0, f64::max)
    })
}

/// The poses that repeat an earlier one: `(index, index of the first,
/// largest corner shift px)`, in order. A pose is one board view per camera
/// (one for a camera, left and right for a pair); it repeats another when
/// every camera's corners lie within [`SAME_POSE_PX`] of the other's.
///
/// # Examples
///
/// ```
/// use fusegraph_nodes::calib::{BoardView, repeated_poses};
/// use nalgebra::Point2;
///
/// let view = |dx: f64| BoardView {
///     board_mm: vec![Point2::new(0.0, 0.0), Point2::new(25.0, 0.0)],
///     image_px: vec![Point2::new(100.0 + dx, 50.0), Point2::new(180.0 + dx, 52.0)],
/// };
/// let (a, b, c) = (view(0.0), view(0.05), view(12.0));
/// let poses = vec![vec![&a], vec![&b], vec![&c]];
/// let repeats = repeated_poses(&poses);
/// assert_eq!(repeats.len(), 1);
/// assert_eq!((repeats[0].0, repeats[0].1), (1, 0));
/// ```
pub fn repeated_poses(poses: &[Vec<&BoardView>]) -> Vec<(usize, usize, f64)> {
    let mut kept: Vec<usize> = Vec::new();
    let mut repeats = Vec::new();
    for (i, pose) in poses.iter().enumerate() {
        let same = kept.iter().find_map(|&k| {
            let shifts: Option<Vec<f64>> = pose
                .iter()
                .zip(&poses[k])
                .map(|(a, b)| max_corner_shift_px(a, b))
                .collect();
            let worst = shifts?.into_iter().fold(0.0, f64::max);
            (worst < SAME_POSE_PX).then_some((k, worst))
        });
        match same {
            Some((k, shift)) => repeats.push((i, k, shift)),
            None => kept.push(i),
        }
    }
    repeats
}

/// The size most views have (ties: the lowest view's) and the views of other
/// sizes, which a calibration leaves out: one camera takes one size, and a
/// photo of another size is a cropped or resized copy.
pub fn usual_size(sizes: &BTreeMap<u32, (usize, usize)>) -> ((usize, usize), Vec<u32>) {
    let mut counts: Vec<((usize, usize), usize)> = Vec::new();
    for s in sizes.values() {
        match counts.iter_mut().find(|(c, _)| c == s) {
            Some((_, n)) => *n += 1,
            None => counts.push((*s, 1)),
        }
    }
    // The first size seen (the lowest view's) wins a tie.
    let mut usual = ((0, 0), 0);
    for &(size, n) in &counts {
        if n > usual.1 {
            usual = (size, n);
        }
    }
    let usual = usual.0;
    let odd = sizes
        .iter()
        .filter(|(_, s)| **s != usual)
        .map(|(v, _)| *v)
        .collect();
    (usual, odd)
}

/// Pairs the left and right boards of each view number. Views with a board on
/// one side only, or whose photos are not the cameras' usual size, are left
/// out and listed; a pair whose two photos differ in size is an error. Fewer
/// than `min_pairs` pairs is an error listing every view's fate on both sides.
pub fn pair_views(left: &Side, right: &Side, min_pairs: usize) -> Result<Pairing, String> {
    let mut all: Vec<u32> = left.views().chain(right.views()).collect();
    all.sort_unstable();
    all.dedup();
    let size_of = |side: &Side, v: u32| {
        side.boards.get(&v).map(|b| b.1).or_else(|| {
            side.photos
                .as_ref()?
                .get(&v)
                .map(|r| r.size)
                .filter(|&s| s != (0, 0))
        })
    };
    for &v in &all {
        if let (Some(l), Some(r)) = (size_of(left, v), size_of(right, v))
            && l != r
        {
            return Err(format!(
                "view {v}: the left photo is {} x {} px but the right one {} x {} px",
                l.0, l.1, r.0, r.1
            ));
        }
    }
    let mut pairing = Pairing {
        views: Vec::new(),
        pairs: Vec::new(),
        sizes: [(0, 0); 2],
        dropped: Vec::new(),
    };
    // A pair's photos have one size (checked above); a pair whose size is not
    // its camera's (a cropped or resized copy) is left out.
    let sizes: BTreeMap<u32, (usize, usize)> = all
        .iter()
        .filter_map(|&v| Some((v, size_of(left, v)?)))
        .collect();
    let (usual, odd) = usual_size(&sizes);
    for &v in &odd {
        let (w, h) = sizes[&v];
        pairing.dropped.push(format!(
            "view {v}: the photos are {w} x {h} px, the others {} x {}",
            usual.0, usual.1
        ));
    }
    for &v in all.iter().filter(|v| !odd.contains(v)) {
        match (left.boards.get(&v), right.boards.get(&v)) {
            (Some((l, ls)), Some((r, rs))) => {
                pairing.views.push(v);
                pairing.pairs.push((l.clone(), r.clone()));
                pairing.sizes = [*ls, *rs];
            }
            _ => pairing.dropped.push(format!(
                "view {v}: left {}, right {}",
                left.fate(v),
                right.fate(v)
            )),
        }
    }
    // A pose photographed twice adds no constraint but weighs double, and
    // makes the fit look better than the rig is.
    let poses: Vec<Vec<&BoardView>> = pairing.pairs.iter().map(|(l, r)| vec![l, r]).collect();
    let repeats = repeated_poses(&poses);
    for (i, first, shift) in repeats.iter().rev() {
        let (v, u) = (pairing.views[*i], pairing.views[*first]);
        pairing.dropped.push(format!(
            "view {v}: the same board pose as view {u} in both photos (corners within {shift:.2} px): a repeated photo"
        ));
        pairing.views.remove(*i);
        pairing.pairs.remove(*i);
    }
    if pairing.pairs.len() < min_pairs {
        return Err(format!(
            "{} usable pair{} of {} views, {min_pairs} needed (the find_chessboard nodes' notes say why each board was refused): {}",
            pairing.pairs.len(),
            if pairing.pairs.len() == 1 { "" } else { "s" },
            all.len(),
            pairing.dropped.join("; ")
        ));
    }
    Ok(pairing)
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Point2;

    #[test]
    fn views_are_numbered_by_the_last_number_in_the_name() {
        assert_eq!(view_number("left_07.png"), Some(7));
        assert_eq!(view_number("right07.jpg"), Some(7));
        assert_eq!(view_number("cam2_shot0042.JPG"), Some(42));
        assert_eq!(view_number("0003_left.png"), Some(3));
        assert_eq!(view_number("left_intrinsics.png"), None);
    }

    fn touch(dir: &Path, names: &[&str]) {
        for n in names {
            std::fs::write(dir.join(n), b"x").unwrap();
        }
    }

    #[test]
    fn non_images_and_unnumbered_files_do_not_shift_the_views() {
        let d = tempfile::tempdir().unwrap();
        touch(
            d.path(),
            &[
                "left_01.png",
                "left_02.png",
                "left_intrinsics.yml",
                "left_notes.png",
                "left_10.png",
            ],
        );
        let p = numbered_photos(d.path(), &glob::Pattern::new("left_*").unwrap()).unwrap();
        assert_eq!(p.files.keys().copied().collect::<Vec<_>>(), [1, 2, 10]);
        assert_eq!(p.skipped.len(), 2, "{:?}", p.skipped);
        assert!(p.skipped[0].starts_with("left_intrinsics.yml: skipped: not an image"));
        assert!(p.skipped[1].starts_with("left_notes.png: skipped: no number"));
        touch(d.path(), &["left_1.png"]);
        let e = numbered_photos(d.path(), &glob::Pattern::new("left_*").unwrap()).unwrap_err();
        assert!(
            e.contains("left_01.png and left_1.png both number view 1"),
            "{e}"
        );
        let e = numbered_photos(d.path(), &glob::Pattern::new("right_*").unwrap()).unwrap_err();
        assert!(e.contains("no image matches \"right_*\""), "{e}");
    }

    fn side(found: &[u32], refused: &[u32], size: (usize, usize)) -> Side {
        // Each view's board somewhere else in the photo: a pose of its own.
        let view = |v: u32| BoardView {
            board_mm: vec![Point2::new(0.0, 0.0)],
            image_px: vec![Point2::new(1.0 + 10.0 * v as f64, 2.0)],
        };
        let mut photos: BTreeMap<u32, PhotoRecord> = BTreeMap::new();
        for &v in found {
            photos.insert(
                v,
                PhotoRecord {
                    refusal: PhotoRecord::FOUND,
                    size,
                },
            );
        }
        for &v in refused {
            let refusal = Refusal::NoCompleteGrid {
                cols: 9,
                rows: 6,
                largest: 0,
            }
            .code();
            photos.insert(v, PhotoRecord { refusal, size });
        }
        Side {
            boards: found.iter().map(|&v| (v, (view(v), size))).collect(),
            photos: Some(photos),
        }
    }

    #[test]
    fn pairs_by_number_and_says_what_each_dropped_view_lacks() {
        // An extra left photo (view 9), a missing right photo (view 4), a
        // refused right board (view 2).
        let left = side(&[1, 2, 3, 4, 5, 9], &[], (640, 480));
        let right = side(&[1, 3, 5], &[2], (640, 480));
        let p = pair_views(&left, &right, 3).unwrap();
        assert_eq!(p.views, [1, 3, 5]);
        assert_eq!(
            p.dropped,
            [
                "view 2: left board found, right board refused (no complete grid)",
                "view 4: left board found, right no photo",
                "view 9: left board found, right no photo",
            ]
        );
        let e = pair_views(&left, &right, 4).unwrap_err();
        assert!(e.starts_with("3 usable pairs of 6 views, 4 needed"), "{e}");
        assert!(
            e.contains("view 2: left board found, right board refused"),
            "{e}"
        );
    }

    #[test]
    fn photos_of_a_pair_must_have_one_size() {
        let left = side(&[1, 2, 3], &[], (640, 480));
        let right = side(&[1, 2, 3], &[], (800, 600));
        let e = pair_views(&left, &right, 3).unwrap_err();
        assert_eq!(
            e,
            "view 1: the left photo is 640 x 480 px but the right one 800 x 600 px"
        );
    }

    #[test]
    fn a_pair_of_another_size_than_the_cameras_is_left_out() {
        // A real set (chessboard_mono) holds one 1281 x 721 photo among
        // 1280 x 720 ones.
        let mut left = side(&[1, 2, 4], &[], (640, 480));
        let mut right = side(&[1, 2, 4], &[], (640, 480));
        for s in [&mut left, &mut right] {
            let view = s.boards[&1].0.clone();
            s.boards.insert(3, (view, (641, 481)));
        }
        let p = pair_views(&left, &right, 3).unwrap();
        assert_eq!(p.views, [1, 2, 4]);
        assert_eq!(
            p.dropped,
            ["view 3: the photos are 641 x 481 px, the others 640 x 480"]
        );
        let sizes = BTreeMap::from([(1, (5, 5)), (2, (6, 6)), (3, (6, 6))]);
        assert_eq!(usual_size(&sizes), ((6, 6), vec![1]));
        let tie = BTreeMap::from([(1, (5, 5)), (2, (6, 6))]);
        assert_eq!(usual_size(&tie), ((5, 5), vec![2]));
    }

    #[test]
    fn a_pair_repeating_another_pose_is_left_out_naming_both() {
        let left = side(&[1, 2, 3, 4], &[], (640, 480));
        let right = side(&[1, 2, 3, 4], &[], (640, 480));
        // View 4 is a copy of view 2 on both sides.
        let copy = |s: &Side| {
            let mut s = s.clone();
            let two = s.boards[&2].clone();
            s.boards.insert(4, two);
            s
        };
        let (left, right) = (copy(&left), copy(&right));
        let p = pair_views(&left, &right, 3).unwrap();
        assert_eq!(p.views, [1, 2, 3]);
        assert_eq!(
            p.dropped,
            [
                "view 4: the same board pose as view 2 in both photos (corners within 0.00 px): a repeated photo"
            ]
        );
        // A copy on one side only is a different pair: kept.
        let right_only = copy(&side(&[1, 2, 3, 4], &[], (640, 480)));
        let p = pair_views(&side(&[1, 2, 3, 4], &[], (640, 480)), &right_only, 3).unwrap();
        assert_eq!(p.views, [1, 2, 3, 4]);
    }
}
