//! Property tests: the parsers never panic, whatever the bytes, and on random valid maps the
//! BFS lengths match a plain reference BFS written here.

use planner::map::{PAPER_10, PAPER_20, parse_ascii, parse_movingai_map, parse_scen};
use planner::path::{bfs_distances, bfs_path};
use planner::task::{parse_cell, resolve_task};
use planner::{Cell, Grid};
use proptest::prelude::*;
use std::collections::VecDeque;

const MOVINGAI: &str = "type octile\nheight 4\nwidth 5\nmap\n..@T.\nO.W..\n.G.S.\n.....\n";
const SCEN: &str =
    "version 1\n0\tm.map\t5\t4\t0\t0\t4\t3\t5.24\n2\tm.map\t5\t4\t1\t2\t3\t0\t2.83\n";

/// Runs every parser on `bytes` and checks that errors render and name a location or path.
fn parse_all(bytes: &[u8]) {
    for result in [
        parse_ascii("fuzz.txt", bytes),
        parse_movingai_map("fuzz.map", bytes),
    ] {
        match result {
            Ok(m) => {
                assert_eq!(m.grid.len(), m.grid.width() * m.grid.height());
                if let Some(s) = m.start {
                    assert!(m.grid.is_free(s));
                }
                assert!(m.goals.iter().all(|g| m.grid.is_free(*g)));
                // A parsed map writes out to text that reads back the same.
                let again = parse_ascii("again.txt", m.to_ascii().as_bytes()).unwrap();
                assert_eq!(again.grid, m.grid);
            }
            Err(e) => {
                let msg = e.to_string();
                assert!(msg.starts_with("fuzz."), "{msg}");
            }
        }
    }
    match parse_scen("fuzz.scen", bytes) {
        Ok(scens) => {
            for s in scens {
                assert!((s.start.x as usize) < s.width && (s.start.y as usize) < s.height);
                assert!((s.goal.x as usize) < s.width && (s.goal.y as usize) < s.height);
                assert!(s.optimal_octile.is_finite() && s.optimal_octile >= 0.0);
            }
        }
        Err(e) => assert!(e.to_string().starts_with("fuzz.scen"), "{e}"),
    }
}

/// One edit to a file: replace, insert or delete a byte, or cut the file short.
#[derive(Debug, Clone)]
enum Edit {
    Replace(usize, u8),
    Insert(usize, u8),
    Delete(usize),
    Truncate(usize),
}

fn edit() -> impl Strategy<Value = Edit> {
    // Bytes that matter to the formats are more likely than arbitrary ones.
    let byte = prop_oneof![
        any::<u8>(),
        prop::sample::select(b"#.SG@OTW\n\r\t ;0123456789-e".to_vec()),
    ];
    prop_oneof![
        (any::<usize>(), byte.clone()).prop_map(|(i, b)| Edit::Replace(i, b)),
        (any::<usize>(), byte).prop_map(|(i, b)| Edit::Insert(i, b)),
        any::<usize>().prop_map(Edit::Delete),
        any::<usize>().prop_map(Edit::Truncate),
    ]
}

fn mutate(seed: &str, edits: &[Edit]) -> Vec<u8> {
    let mut bytes = seed.as_bytes().to_vec();
    for e in edits {
        let n = bytes.len();
        match *e {
            Edit::Replace(i, b) if n > 0 => bytes[i % n] = b,
            Edit::Insert(i, b) => bytes.insert(i % (n + 1), b),
            Edit::Delete(i) if n > 0 => {
                bytes.remove(i % n);
            }
            Edit::Truncate(i) => bytes.truncate(i % (n + 1)),
            _ => {}
        }
    }
    bytes
}

/// Moves from `from` to every cell by a plain queue BFS; `None` where blocked or unreachable.
fn reference_bfs(w: usize, h: usize, free: &[bool], from: usize) -> Vec<Option<u32>> {
    let mut dist = vec![None; w * h];
    if !free[from] {
        return dist;
    }
    dist[from] = Some(0);
    let mut queue = VecDeque::from([from]);
    while let Some(i) = queue.pop_front() {
        let (x, y) = (i % w, i / w);
        let d = dist[i].unwrap();
        let mut next = Vec::new();
        if x > 0 {
            next.push(i - 1);
        }
        if x + 1 < w {
            next.push(i + 1);
        }
        if y > 0 {
            next.push(i - w);
        }
        if y + 1 < h {
            next.push(i + w);
        }
        for j in next {
            if free[j] && dist[j].is_none() {
                dist[j] = Some(d + 1);
                queue.push_back(j);
            }
        }
    }
    dist
}

/// A random small map: width, height, free flags, and a start and goal index.
fn small_map() -> impl Strategy<Value = (usize, usize, Vec<bool>, usize, usize)> {
    (1usize..=12, 1usize..=12).prop_flat_map(|(w, h)| {
        (
            Just(w),
            Just(h),
            prop::collection::vec(prop::bool::weighted(0.7), w * h),
            0..w * h,
            0..w * h,
        )
    })
}

fn ascii_text(w: usize, free: &[bool], start: usize, goal: usize) -> String {
    let mut text = String::from("; generated\n");
    for (i, f) in free.iter().enumerate() {
        text.push(if i == start {
            'S'
        } else if i == goal {
            'G'
        } else if *f {
            '.'
        } else {
            '#'
        });
        if (i + 1) % w == 0 {
            text.push('\n');
        }
    }
    text
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(512))]

    #[test]
    fn arbitrary_bytes_never_panic(bytes in prop::collection::vec(any::<u8>(), 0..600)) {
        parse_all(&bytes);
    }

    #[test]
    fn mutated_ascii_never_panics(edits in prop::collection::vec(edit(), 1..8)) {
        parse_all(&mutate(PAPER_10, &edits));
    }

    #[test]
    fn mutated_movingai_never_panics(edits in prop::collection::vec(edit(), 1..8)) {
        parse_all(&mutate(MOVINGAI, &edits));
    }

    #[test]
    fn mutated_scen_never_panics(edits in prop::collection::vec(edit(), 1..8)) {
        parse_all(&mutate(SCEN, &edits));
    }

    #[test]
    fn lying_movingai_headers_never_panic(h in 0usize..9000, w in 0usize..9000, rows in 0usize..6) {
        let mut text = format!("type octile\nheight {h}\nwidth {w}\nmap\n");
        for _ in 0..rows {
            text.push_str(&".".repeat(w.min(40)));
            text.push('\n');
        }
        parse_all(text.as_bytes());
    }

    #[test]
    fn parse_cell_never_panics(s in ".{0,24}") {
        if let Ok(c) = parse_cell(&s) {
            prop_assert_eq!(parse_cell(&c.to_string()), Ok(c));
        }
    }

    #[test]
    fn parse_cell_reads_what_display_writes(x in any::<u16>(), y in any::<u16>()) {
        prop_assert_eq!(parse_cell(&format!("{x},{y}")), Ok(Cell::new(x, y)));
    }

    #[test]
    fn bfs_matches_a_reference_bfs((w, h, mut free, start, goal) in small_map()) {
        free[start] = true;
        free[goal] = true;
        let m = parse_ascii("r.txt", ascii_text(w, &free, start, goal).as_bytes()).unwrap();
        prop_assert_eq!(m.grid.free_flags(), &free[..]);
        let (s, g) = (m.grid.cell(start), m.grid.cell(goal));
        prop_assert_eq!(m.start, Some(s));

        let reference = reference_bfs(w, h, &free, goal);
        // bfs_distances agrees cell by cell (moves are reversible).
        let dist = bfs_distances(&m.grid, g);
        let expected: Vec<u32> = reference.iter().map(|d| d.unwrap_or(u32::MAX)).collect();
        prop_assert_eq!(&dist, &expected);

        // bfs_path has the reference length and is a real path.
        let path = bfs_path(&m.grid, s, g);
        prop_assert_eq!(path.as_ref().map(|p| p.len() as u32 - 1), reference[start]);
        if let Some(p) = path {
            prop_assert_eq!(p[0], s);
            prop_assert_eq!(*p.last().unwrap(), g);
            for step in p.windows(2) {
                prop_assert_eq!(step[0].manhattan(step[1]), 1);
                prop_assert!(m.grid.is_free(step[1]));
            }
        }

        // resolve_task reports the same optimum, or why there is none.
        match resolve_task(&m, None, None) {
            Ok(t) => prop_assert_eq!(Some(t.optimal_len), reference[start]),
            Err(_) => prop_assert!(start == goal || reference[start].is_none()),
        }
    }

    #[test]
    fn movingai_text_reads_like_ascii((w, h, free, _s, _g) in small_map(), pick in any::<u64>()) {
        // Passable and blocked characters chosen per cell from each set.
        let mut text = format!("type octile\nheight {h}\nwidth {w}\nmap\n");
        for (i, f) in free.iter().enumerate() {
            let k = (pick.rotate_left(i as u32 % 64) as usize) % 4;
            text.push(if *f { ['.', 'G', 'S', '.'][k] } else { ['@', 'O', 'T', 'W'][k] });
            if (i + 1) % w == 0 {
                text.push_str(if i % 2 == 0 { "\r\n" } else { "\n" });
            }
        }
        let m = parse_movingai_map("r.map", text.as_bytes()).unwrap();
        prop_assert_eq!(m.grid, Grid::new(w, h, free).unwrap());
    }

    #[test]
    fn scen_lines_read_back(
        rows in prop::collection::vec(
            (any::<u32>(), 1usize..=4096, 1usize..=4096, any::<u16>(), any::<u16>(), any::<u16>(), any::<u16>(), 0.0f64..1e6),
            0..20,
        )
    ) {
        let mut text = String::from("version 1\n");
        let mut expected = Vec::new();
        for (bucket, w, h, sx, sy, gx, gy, opt) in rows {
            let (sx, sy, gx, gy) = (sx as usize % w, sy as usize % h, gx as usize % w, gy as usize % h);
            text.push_str(&format!("{bucket}\tm.map\t{w}\t{h}\t{sx}\t{sy}\t{gx}\t{gy}\t{opt}\n"));
            expected.push((bucket, w, h, Cell::new(sx as u16, sy as u16), Cell::new(gx as u16, gy as u16), opt));
        }
        let got = parse_scen("r.scen", text.as_bytes()).unwrap();
        prop_assert_eq!(got.len(), expected.len());
        for (s, (bucket, w, h, start, goal, opt)) in got.iter().zip(expected) {
            prop_assert_eq!((s.bucket, s.width, s.height, s.start, s.goal), (bucket, w, h, start, goal));
            prop_assert_eq!(s.optimal_octile, opt);
            prop_assert_eq!(s.map.as_str(), "m.map");
        }
    }
}

#[test]
fn seeds_parse() {
    assert!(parse_ascii("p20", PAPER_20.as_bytes()).is_ok());
    assert!(parse_movingai_map("m.map", MOVINGAI.as_bytes()).is_ok());
    assert_eq!(parse_scen("m.scen", SCEN.as_bytes()).unwrap().len(), 2);
}
