//! A work-stealing pool for the runs a study repeats (sweep points, seeds): a few workers, each
//! taking the next item as it frees up, so that long and short runs share the cores.

use std::sync::atomic::{AtomicUsize, Ordering};

/// `f` on every item over `threads` workers (at least one); the results in the items' order.
pub fn map<T: Sync, R: Send>(items: &[T], threads: usize, f: impl Fn(&T) -> R + Sync) -> Vec<R> {
    map_until(items.len(), threads, || false, |i| f(&items[i]))
        .into_iter()
        .map(|(_, r)| r)
        .collect()
}

/// `f` on each index 0..`n` over `threads` workers (at least one), each result with its index,
/// in the indices' order; once `stop()` says so the workers take no further index (Ctrl-C: a
/// million items are not walked through one by one), and those indices have no result. Nothing
/// is allocated per index up front: a worker keeps the results it made.
pub fn map_until<R: Send>(
    n: usize,
    threads: usize,
    stop: impl Fn() -> bool + Sync,
    f: impl Fn(usize) -> R + Sync,
) -> Vec<(usize, R)> {
    let next = AtomicUsize::new(0);
    let mut all: Vec<(usize, R)> = std::thread::scope(|scope| {
        let workers: Vec<_> = (0..threads.max(1))
            .map(|_| {
                scope.spawn(|| {
                    let mut mine = Vec::new();
                    while !stop() {
                        let i = next.fetch_add(1, Ordering::Relaxed);
                        if i >= n {
                            break;
                        }
                        mine.push((i, f(i)));
                    }
                    mine
                })
            })
            .collect();
        workers
            .into_iter()
            .flat_map(|w| match w.join() {
                Ok(mine) => mine,
                Err(panic) => std::panic::resume_unwind(panic),
            })
            .collect()
    });
    all.sort_unstable_by_key(|(i, _)| *i);
    all
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

    #[test]
    fn map_until_takes_no_index_once_told_to_stop() {
        let done = std::sync::atomic::AtomicUsize::new(0);
        let out = super::map_until(
            1_000_000,
            2,
            || done.load(std::sync::atomic::Ordering::Relaxed) >= 10,
            |i| {
                done.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
                i
            },
        );
        assert!((10..=12).contains(&out.len()), "{}", out.len());
        assert!(out.windows(2).all(|w| w[0].0 < w[1].0), "in order: {out:?}");
        assert!(out.iter().all(|(i, r)| i == r));
    }
}
