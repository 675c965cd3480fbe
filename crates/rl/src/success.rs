//! The rolling success rate of one task's last episodes, shared by the trainer, the learner,
//! the selector and the PTR gate.

use std::collections::VecDeque;

/// The outcomes (success or not) of a task's last `capacity` episodes, oldest first, and
/// their success rate.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct SuccessWindow {
    capacity: usize,
    recent: VecDeque<bool>,
    successes: usize,
}

impl SuccessWindow {
    /// An empty window over the last `capacity` episodes (a capacity of 0 is taken as 1).
    pub fn new(capacity: usize) -> Self {
        let capacity = capacity.max(1);
        Self {
            capacity,
            recent: VecDeque::with_capacity(capacity),
            successes: 0,
        }
    }

    /// Records one finished episode; the oldest one leaves once the window is full.
    pub fn push(&mut self, success: bool) {
        if self.recent.len() == self.capacity {
            let old = self.recent.pop_front().expect("a full window is not empty");
            self.successes -= usize::from(old);
        }
        self.recent.push_back(success);
        self.successes += usize::from(success);
    }

    /// Fraction of the episodes in the window that succeeded, in `[0, 1]`; 0 when empty.
    pub fn rate(&self) -> f64 {
        if self.recent.is_empty() {
            0.0
        } else {
            self.successes as f64 / self.recent.len() as f64
        }
    }

    /// Episodes in the window (at most [`Self::capacity`]).
    pub fn len(&self) -> usize {
        self.recent.len()
    }

    /// Whether no episode has been recorded yet.
    pub fn is_empty(&self) -> bool {
        self.recent.is_empty()
    }

    /// Most episodes the window holds.
    pub fn capacity(&self) -> usize {
        self.capacity
    }

    /// Successes among the episodes in the window.
    pub fn successes(&self) -> usize {
        self.successes
    }

    /// The outcomes in the window, oldest first.
    pub fn iter(&self) -> impl Iterator<Item = bool> + '_ {
        self.recent.iter().copied()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn an_empty_window_has_rate_zero() {
        let w = SuccessWindow::new(4);
        assert!(w.is_empty());
        assert_eq!((w.len(), w.successes(), w.rate()), (0, 0, 0.0));
    }

    #[test]
    fn the_window_keeps_only_the_last_capacity_episodes() {
        let mut w = SuccessWindow::new(3);
        for s in [true, true, false] {
            w.push(s);
        }
        assert_eq!(w.len(), 3);
        assert!((w.rate() - 2.0 / 3.0).abs() < 1e-12);
        // The two successes leave, one by one.
        w.push(false);
        assert_eq!((w.len(), w.successes()), (3, 1));
        w.push(false);
        assert_eq!((w.len(), w.successes(), w.rate()), (3, 0, 0.0));
        w.push(true);
        assert_eq!(w.iter().collect::<Vec<_>>(), [false, false, true]);
        assert!((w.rate() - 1.0 / 3.0).abs() < 1e-12);
    }

    #[test]
    fn the_rate_is_over_the_episodes_seen_until_the_window_fills() {
        let mut w = SuccessWindow::new(10);
        w.push(true);
        w.push(false);
        assert_eq!(w.len(), 2);
        assert!((w.rate() - 0.5).abs() < 1e-12);
    }

    #[test]
    fn a_zero_capacity_window_holds_one_episode() {
        let mut w = SuccessWindow::new(0);
        assert_eq!(w.capacity(), 1);
        w.push(false);
        w.push(true);
        assert_eq!((w.len(), w.rate()), (1, 1.0));
    }
}
