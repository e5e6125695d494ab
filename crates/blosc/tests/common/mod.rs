//! Loads the c-blosc test vectors made by scripts/make_blosc_vectors.py.
#![allow(dead_code)]

use std::collections::HashMap;
use std::path::PathBuf;

/// One line of tests/data/manifest.tsv.
#[derive(Debug, Clone)]
pub struct Vector {
    pub name: String,
    pub dataset: String,
    pub nbytes: usize,
    pub codec: String,
    pub clevel: u8,
    pub shuffle: String,
    pub typesize: u8,
    pub blocksize_arg: usize,
    pub splitmode: String,
    pub flags: u8,
    pub offset: usize,
    pub length: usize,
    /// Whether c-blosc itself decodes this buffer.
    pub c_decodes: bool,
    pub sha256: String,
}

pub struct Vectors {
    pub vectors: Vec<Vector>,
    blob: Vec<u8>,
    datasets: HashMap<String, Vec<u8>>,
}

impl Vectors {
    /// The compressed buffer of `v`.
    pub fn compressed(&self, v: &Vector) -> &[u8] {
        &self.blob[v.offset..v.offset + v.length]
    }

    /// What `v` decodes to (the dataset, cut to its length).
    pub fn expected(&self, v: &Vector) -> &[u8] {
        &self.datasets[&v.dataset][..v.nbytes]
    }

    pub fn by_name(&self, name: &str) -> &Vector {
        self.vectors.iter().find(|v| v.name == name).unwrap_or_else(|| panic!("no vector named {name}"))
    }
}

fn data_dir() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests").join("data")
}

pub fn load() -> Vectors {
    let dir = data_dir();
    let manifest = std::fs::read_to_string(dir.join("manifest.tsv")).expect("read manifest.tsv");
    let blob = std::fs::read(dir.join("vectors.bin")).expect("read vectors.bin");
    let mut vectors = Vec::new();
    let mut datasets = HashMap::new();
    for line in manifest.lines().filter(|l| !l.starts_with('#') && !l.is_empty()) {
        let f: Vec<&str> = line.split('\t').collect();
        assert_eq!(f.len(), 14, "bad manifest line: {line}");
        let v = Vector {
            name: f[0].to_string(),
            dataset: f[1].to_string(),
            nbytes: f[2].parse().unwrap(),
            codec: f[3].to_string(),
            clevel: f[4].parse().unwrap(),
            shuffle: f[5].to_string(),
            typesize: f[6].parse().unwrap(),
            blocksize_arg: f[7].parse().unwrap(),
            splitmode: f[8].to_string(),
            flags: u8::from_str_radix(f[9].trim_start_matches("0x"), 16).unwrap(),
            offset: f[10].parse().unwrap(),
            length: f[11].parse().unwrap(),
            c_decodes: match f[12] {
                "ok" => true,
                "err" => false,
                other => panic!("bad expect field {other}"),
            },
            sha256: f[13].to_string(),
        };
        assert!(v.offset + v.length <= blob.len(), "{} runs past vectors.bin", v.name);
        datasets.entry(v.dataset.clone()).or_insert_with(|| std::fs::read(dir.join("datasets").join(format!("{}.bin", v.dataset))).expect("read dataset"));
        vectors.push(v);
    }
    assert!(vectors.len() > 100, "manifest has only {} vectors", vectors.len());
    Vectors { vectors, blob, datasets }
}

/// A small deterministic PRNG (xorshift64*).
pub struct Rng(pub u64);

impl Rng {
    pub fn next(&mut self) -> u64 {
        let mut x = self.0;
        x ^= x >> 12;
        x ^= x << 25;
        x ^= x >> 27;
        self.0 = x;
        x.wrapping_mul(0x2545_F491_4F6C_DD1D)
    }

    pub fn below(&mut self, n: usize) -> usize {
        (self.next() % n as u64) as usize
    }
}
