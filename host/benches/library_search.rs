//! `gonio library search` at scale (issue 29): synthetic libraries of N stocks × 5 sheets ×
//! 5 spots (`host::study::library_scale`), imported with `gonio library import`, then
//! searched with the gonio binary as a user runs it, each run under `/usr/bin/time -v` for
//! its wall time and peak resident memory:
//!
//! - the first search of the library's contents, which makes the population (and caches
//!   it in the library);
//! - the searches after it (the population read from the cache): what an examiner waits
//!   for, three of them, the median reported;
//! - `gonio library export` of the whole library.
//!
//! `cargo bench -p host --bench library_search -- 2000 20000` (stock counts; default
//! both). Libraries are made in a temporary folder and removed after. With
//! `GONIO_BENCH_POSTGRES=URL` (an administrator's URL of a PostgreSQL server, as
//! `.ci/postgres start` prints) each size is measured on PostgreSQL too, in a database made
//! for it and dropped after (`GONIO_BENCH_KEEP=1` keeps the libraries, and says where). Not a criterion
//! benchmark: one search of 20,000 stocks is seconds, and what matters is the wall time
//! and memory of the whole command, loading included.
use host::study::library_scale::{Shape, write_library, write_questioned};
use std::path::Path;
use std::process::Command;
use std::time::Instant;

/// What `/usr/bin/time -v` reported of one run.
struct Run {
    wall_s: f64,
    peak_rss_mib: f64,
    stdout: String,
}

fn run(args: &[&std::ffi::OsStr]) -> Run {
    let start = Instant::now();
    let out = Command::new("/usr/bin/time")
        .arg("-v")
        .arg(env!("CARGO_BIN_EXE_gonio"))
        .args(args)
        .env("GONIO_NO_BROWSER", "1")
        .output()
        .expect("run /usr/bin/time -v gonio");
    let wall_s = start.elapsed().as_secs_f64();
    let stderr = String::from_utf8_lossy(&out.stderr);
    let code = out.status.code().unwrap_or(-1);
    // 0: done; 3: done with warnings (a population not validated is one).
    assert!(
        code == 0 || code == 3,
        "gonio {args:?} exited {code}: {stderr}"
    );
    let peak_kib: f64 = stderr
        .lines()
        .find_map(|l| {
            l.trim()
                .strip_prefix("Maximum resident set size (kbytes): ")
        })
        .and_then(|v| v.trim().parse().ok())
        .expect("/usr/bin/time -v reports the peak resident set size");
    Run {
        wall_s,
        peak_rss_mib: peak_kib / 1024.0,
        stdout: String::from_utf8_lossy(&out.stdout).into_owned(),
    }
}

fn os(s: &str) -> &std::ffi::OsStr {
    std::ffi::OsStr::new(s)
}

/// Where a benchmark's library is kept.
enum Backend {
    Sqlite,
    /// An administrator's URL of the server.
    Postgres(String),
}

/// `admin` with its database replaced.
fn database_url(admin: &str, database: &str) -> String {
    let (head, tail) = admin.rsplit_once('/').expect("a database in the URL");
    let query = tail
        .split_once('?')
        .map(|(_, q)| format!("?{q}"))
        .unwrap_or_default();
    format!("{head}/{database}{query}")
}

fn bench(stocks: usize, root: &Path, backend: &Backend) -> (f64, f64) {
    let shape = Shape {
        stocks,
        sheets: 5,
        spots: 5,
        seed: 29,
    };
    let dir = root.join(format!("stocks-{stocks}"));
    std::fs::create_dir_all(&dir).expect("temp dir");
    let exchange = dir.join("library.jsonl");
    let records = {
        let mut file = std::fs::File::create(&exchange).expect("exchange file");
        write_library(&shape, &mut file).expect("write the library")
    };
    let (library, label) = match backend {
        Backend::Sqlite => (dir.join("library.sqlite").into_os_string(), "SQLite"),
        Backend::Postgres(admin) => {
            let name = format!("gonio_bench_{stocks}_{}", std::process::id());
            let mut client = postgres::Client::connect(admin, postgres::NoTls).expect("server");
            for sql in [
                format!("DROP DATABASE IF EXISTS {name} WITH (FORCE)"),
                format!("CREATE DATABASE {name} ENCODING 'UTF8' TEMPLATE template0"),
            ] {
                client.batch_execute(&sql).expect("a database");
            }
            (database_url(admin, &name).into(), "PostgreSQL")
        }
    };
    let library = library.as_os_str();
    let import = run(&[
        os("library"),
        os("--library"),
        library,
        os("import"),
        exchange.as_os_str(),
    ]);
    std::fs::remove_file(&exchange).ok();
    let questioned = write_questioned(&shape, stocks / 3, 1, &dir, "questioned").expect("query");
    let search = || {
        run(&[
            os("library"),
            os("--library"),
            library,
            os("search"),
            questioned.as_os_str(),
            os("--top"),
            os("5"),
            os("--json"),
        ])
    };
    let first = search();
    let mut cached: Vec<Run> = (0..3).map(|_| search()).collect();
    cached.sort_by(|a, b| a.wall_s.total_cmp(&b.wall_s));
    let median = &cached[1];
    let top: serde_json::Value = serde_json::from_str(&median.stdout).expect("search's JSON");
    let rank1 = top["ranking"][0]["stock"]
        .as_str()
        .unwrap_or("?")
        .to_string();
    let out = dir.join("export.jsonl");
    let export = run(&[
        os("library"),
        os("--library"),
        library,
        os("export"),
        out.as_os_str(),
    ]);
    println!(
        "{label:<10} {stocks:>6} stocks ({records} spots): import {:.1} s {:.0} MiB | first search {:.2} s {:.0} MiB | search {:.2} s {:.0} MiB (median of 3; rank 1 {rank1}, true {}) | export {:.1} s {:.0} MiB",
        import.wall_s,
        import.peak_rss_mib,
        first.wall_s,
        first.peak_rss_mib,
        median.wall_s,
        median.peak_rss_mib,
        host::study::library_scale::stock_name(stocks / 3),
        export.wall_s,
        export.peak_rss_mib,
    );
    if std::env::var_os("GONIO_BENCH_KEEP").is_some() {
        println!("kept: {} ({})", dir.display(), library.to_string_lossy());
        return (first.wall_s, median.wall_s);
    }
    std::fs::remove_dir_all(&dir).ok();
    if let Backend::Postgres(admin) = backend {
        let name = library.to_string_lossy();
        let name = name.rsplit('/').next().unwrap_or_default();
        let mut client = postgres::Client::connect(admin, postgres::NoTls).expect("server");
        let _ = client.batch_execute(&format!("DROP DATABASE IF EXISTS {name} WITH (FORCE)"));
    }
    (first.wall_s, median.wall_s)
}

fn main() {
    let sizes: Vec<usize> = std::env::args()
        .skip(1)
        .filter_map(|a| a.parse().ok())
        .collect();
    let sizes = if sizes.is_empty() {
        vec![2_000, 20_000]
    } else {
        sizes
    };
    let root = tempfile::tempdir().expect("temp dir");
    // GONIO_BENCH_KEEP=1: the libraries (files, databases) are kept to be looked at.
    let root_path = if std::env::var_os("GONIO_BENCH_KEEP").is_some() {
        root.keep()
    } else {
        root.path().to_path_buf()
    };
    let mut backends = vec![Backend::Sqlite];
    if let Ok(admin) = std::env::var("GONIO_BENCH_POSTGRES") {
        backends.push(Backend::Postgres(admin));
    }
    for backend in &backends {
        let times: Vec<(usize, (f64, f64))> = sizes
            .iter()
            .map(|&n| (n, bench(n, &root_path, backend)))
            .collect();
        if let [(n0, (f0, s0)), .., (n1, (f1, s1))] = times.as_slice() {
            println!(
                "from {n0} to {n1} stocks ({:.0}×): first search {:.1}× the time, cached search {:.1}×",
                *n1 as f64 / *n0 as f64,
                f1 / f0,
                s1 / s0
            );
        }
    }
}
