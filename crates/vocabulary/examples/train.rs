//! Trains a vocabulary from a descriptor pack and writes it; optionally exports DBoW2 text and
//! evaluates place recognition on a second pack of consecutive frames.
//!
//! Descriptor pack (written by `scripts/train_vocabulary.py`): for each image in order, a
//! little-endian `u32` descriptor count `n` followed by `n` raw 32-byte ORB descriptors.
//! Image boundaries are kept because the IDF weights count images.
//!
//! ```text
//! cargo run --release -p ferroslam-vocabulary --example train -- PACK OUT.bin \
//!     [--k 10] [--levels 5] [--seed 0] [--iterations 10] [--text OUT.txt] \
//!     [--eval PACK] [--near 2] [--far 150]
//! ```
//!
//! `--eval`: for every frame i with a frame i + far, compares the BoW score of (i, i + near)
//! with that of (i, i + far) and prints the fraction of frames where the near one wins.

use std::time::Instant;

use ferroslam_features::Descriptor;
use ferroslam_vocabulary::{TrainParams, Vocabulary};

type Error = Box<dyn std::error::Error>;

fn read_pack(path: &str) -> Result<Vec<Vec<Descriptor>>, Error> {
    let bytes = std::fs::read(path)?;
    let mut images = Vec::new();
    let mut rest = bytes.as_slice();
    while !rest.is_empty() {
        let (count, tail) = rest
            .split_at_checked(4)
            .ok_or("pack truncated in a count")?;
        let n = u32::from_le_bytes([count[0], count[1], count[2], count[3]]) as usize;
        let (rows, tail) = tail
            .split_at_checked(n.checked_mul(32).ok_or("bad count")?)
            .ok_or("pack truncated in descriptors")?;
        images.push(
            rows.chunks_exact(32)
                .map(|c| core::array::from_fn(|i| c[i]))
                .collect(),
        );
        rest = tail;
    }
    Ok(images)
}

struct Args {
    pack: String,
    out: String,
    params: TrainParams,
    text: Option<String>,
    eval: Option<String>,
    near: usize,
    far: usize,
}

fn parse_args() -> Result<Args, Error> {
    let mut positional = Vec::new();
    let mut args = Args {
        pack: String::new(),
        out: String::new(),
        params: TrainParams::default(),
        text: None,
        eval: None,
        near: 2,
        far: 150,
    };
    let mut it = std::env::args().skip(1);
    while let Some(a) = it.next() {
        let mut value = || it.next().ok_or_else(|| format!("{a} needs a value"));
        match a.as_str() {
            "--k" => args.params.k = value()?.parse()?,
            "--levels" => args.params.levels = value()?.parse()?,
            "--seed" => args.params.seed = value()?.parse()?,
            "--iterations" => args.params.max_iterations = value()?.parse()?,
            "--text" => args.text = Some(value()?),
            "--eval" => args.eval = Some(value()?),
            "--near" => args.near = value()?.parse()?,
            "--far" => args.far = value()?.parse()?,
            _ if a.starts_with("--") => return Err(format!("unknown option {a}").into()),
            _ => positional.push(a),
        }
    }
    let [pack, out]: [String; 2] = positional
        .try_into()
        .map_err(|_| "usage: train PACK OUT [--k K] [--levels L] [--seed S] [--iterations N] [--text TXT] [--eval PACK] [--near N] [--far F]")?;
    args.pack = pack;
    args.out = out;
    Ok(args)
}

fn main() -> Result<(), Error> {
    let args = parse_args()?;
    let images = read_pack(&args.pack)?;
    let total: usize = images.iter().map(Vec::len).sum();
    println!(
        "training on {total} descriptors from {} images, k = {}, L = {}",
        images.len(),
        args.params.k,
        args.params.levels
    );
    let t = Instant::now();
    let voc = Vocabulary::train(&images, &args.params)?;
    println!(
        "trained in {:.2} s: {} nodes, {} words",
        t.elapsed().as_secs_f64(),
        voc.node_count(),
        voc.word_count()
    );
    voc.save(&args.out)?;
    let t = Instant::now();
    let loaded = Vocabulary::load(&args.out)?;
    println!(
        "wrote {} ({} bytes); loads in {:.1} ms",
        args.out,
        std::fs::metadata(&args.out)?.len(),
        t.elapsed().as_secs_f64() * 1e3
    );
    if loaded != voc {
        return Err("reloaded vocabulary differs".into());
    }
    if let Some(text) = &args.text {
        voc.save_dbow2_text(text)?;
        println!("wrote DBoW2 text {text}");
    }
    if let Some(eval) = &args.eval {
        evaluate(&voc, &read_pack(eval)?, args.near, args.far);
    }
    Ok(())
}

fn evaluate(voc: &Vocabulary, frames: &[Vec<Descriptor>], near: usize, far: usize) {
    let t = Instant::now();
    let bows: Vec<_> = frames.iter().map(|f| voc.transform(f, 4).0).collect();
    let per_frame_ms = t.elapsed().as_secs_f64() * 1e3 / frames.len().max(1) as f64;
    let pairs: Vec<(f64, f64)> = (0..frames.len().saturating_sub(far))
        .map(|i| {
            (
                bows[i].l1_score(&bows[i + near]),
                bows[i].l1_score(&bows[i + far]),
            )
        })
        .collect();
    let wins = pairs.iter().filter(|(n, f)| n > f).count();
    let mean = |sel: fn(&(f64, f64)) -> f64| {
        pairs.iter().map(sel).sum::<f64>() / pairs.len().max(1) as f64
    };
    println!(
        "eval on {} frames (transform {:.2} ms/frame): score(i, i+{near}) > score(i, i+{far}) for {wins}/{} frames ({:.3}); mean scores {:.3} vs {:.3}",
        frames.len(),
        per_frame_ms,
        pairs.len(),
        wins as f64 / pairs.len().max(1) as f64,
        mean(|p| p.0),
        mean(|p| p.1)
    );
    println!(
        "near_far_fraction {:.6}",
        wins as f64 / pairs.len().max(1) as f64
    );
}
