//! A work-stealing pool for the runs a study repeats (sweep points, seeds): a few workers, each
//! taking the next item as it frees up, so that long and short runs share the cores.

use std::sync::Mutex;
use std::sync::atomic::{AtomicUsize, Ordering};

/// `f` on every item over `threads` workers (at least one); the results in the items' order.
pub fn map<T: Sync, R: Send>(items: &[T], threads: usize, f: impl Fn(&T) -> R + Sync) -> Vec<R> {
    let results: Mutex<Vec<Option<R>>> = Mutex::new((0..items.len()).map(|_| None).collect());
    let next = AtomicUsize::new(0);
    std::thread::scope(|scope| {
        for _ in 0..threads.max(1) {
            scope.spawn(|| {
                loop {
                    let i = next.fetch_add(1, Ordering::Relaxed);
                    let Some(item) = items.get(i) else { break };
                    let r = f(item);
                    results.lock().expect("pool results")[i] = Some(r);
                }
            });
        }
    });
    results
        .into_inner()
        .expect("pool results")
        .into_iter()
        .map(|r| r.expect("a worker takes every item"))
        .collect()
}

#[cfg(test)]
mod tests {
    #[test]
    fn results_come_back_in_the_items_order_whatever_finishes_first() {
        let items: Vec<u64> = (0..40).collect();
        let out = super::map(&items, 3, |&x| {
            // Early items take longest, so later ones finish first.
            std::thread::sleep(std::time::Duration::from_micros((40 - x) * 50));
            x * x
        });
        assert_eq!(out, items.iter().map(|x| x * x).collect::<Vec<_>>());
        assert!(super::map(&[] as &[u8], 2, |&x| x).is_empty());
        assert_eq!(super::map(&[7u8], 0, |&x| x + 1), vec![8]);
    }
}
