//! The deltaloop supervisor: scenarios and references, the loop runners, metrics, reports, and the
//! `deltaloop` CLI. Its two bottom layers, the study ([`study::scenario`], [`study::reference`],
//! [`study::analysis`]) and the recorder with its metrics ([`record::metrics`]), are the
//! `deltaloop-study` crate (`supervisor/study`), re-exported here; they do no I/O.

pub mod cmd;
pub mod loops;
pub mod ops;
pub mod output;
pub use deltaloop_study::record;
pub mod timing;
pub use deltaloop_study as study;

/// The unit tests' allocator: the system's, counting each thread's allocations, so a test can
/// hold a per-tick path to its allocation budget (other tests run on other threads).
#[cfg(test)]
pub(crate) mod alloc_count {
    use std::alloc::{GlobalAlloc, Layout, System};
    use std::cell::Cell;

    thread_local! {
        static ALLOCATIONS: Cell<u64> = const { Cell::new(0) };
    }

    struct Counting;

    // SAFETY: every call is forwarded to the system allocator unchanged.
    unsafe impl GlobalAlloc for Counting {
        unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
            ALLOCATIONS.with(|n| n.set(n.get() + 1));
            unsafe { System.alloc(layout) }
        }
        unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
            unsafe { System.dealloc(ptr, layout) }
        }
        unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
            ALLOCATIONS.with(|n| n.set(n.get() + 1));
            unsafe { System.realloc(ptr, layout, new_size) }
        }
    }

    #[global_allocator]
    static COUNTING: Counting = Counting;

    /// Allocations (and reallocations) this thread has made so far.
    pub fn allocations() -> u64 {
        ALLOCATIONS.with(Cell::get)
    }
}

/// The layers, bottom up, and which of the others each one's code may name (`crate::<layer>`).
/// `cmd` may use everything and nothing uses `cmd`; doc comments are not checked. Below them all,
/// and free to every layer, `study` and `record` (the `deltaloop-study` crate, which cannot name
/// the supervisor).
#[cfg(test)]
const LAYERS: [(&str, &[&str]); 5] = [
    ("timing", &[]),
    ("output", &["timing"]),
    ("loops", &["timing", "output"]),
    ("ops", &["timing", "output", "loops"]),
    ("cmd", &["timing", "output", "loops", "ops"]),
];

#[cfg(test)]
mod tests {
    use super::LAYERS;
    use std::path::Path;

    fn rust_files(dir: &Path, out: &mut Vec<std::path::PathBuf>) {
        for e in std::fs::read_dir(dir).unwrap().flatten() {
            let p = e.path();
            if p.is_dir() {
                rust_files(&p, out);
            } else if p.extension().is_some_and(|x| x == "rs") {
                out.push(p);
            }
        }
    }

    /// Every module file is in a layer folder, and no layer names one it may not use (above all:
    /// nothing outside `cmd/` uses `cmd`).
    #[test]
    fn each_layer_uses_only_the_layers_below_it() {
        let src = Path::new(env!("CARGO_MANIFEST_DIR")).join("src");
        let mut offenders = Vec::new();
        for e in std::fs::read_dir(&src).unwrap().flatten() {
            let name = e.file_name().to_string_lossy().into_owned();
            if name != "lib.rs" && !LAYERS.iter().any(|(l, _)| *l == name) {
                offenders.push(format!("src/{name} is outside the layer folders"));
            }
        }
        for (layer, allowed) in LAYERS {
            let mut files = Vec::new();
            rust_files(&src.join(layer), &mut files);
            for f in files {
                let text = std::fs::read_to_string(&f).unwrap();
                for (n, line) in text.lines().enumerate() {
                    if line.trim_start().starts_with("//") {
                        continue;
                    }
                    for (other, _) in LAYERS {
                        let named = line.contains(&format!("crate::{other}::"))
                            || line.contains(&format!("crate::{other};"))
                            || line.contains(&format!("crate::{other}::{{"))
                            || line.contains(&format!("crate::{{{other}"));
                        if other != layer && named && !allowed.contains(&other) {
                            offenders.push(format!(
                                "{}:{}: {layer} uses {other}",
                                f.strip_prefix(&src).unwrap().display(),
                                n + 1
                            ));
                        }
                    }
                }
            }
        }
        assert!(offenders.is_empty(), "{offenders:#?}");
    }
}
