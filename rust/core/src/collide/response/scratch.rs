//! Per-thread candidate lists reused from one skin element to the next.

use std::cell::RefCell;
use std::thread::LocalKey;

thread_local! {
    /// Per-thread lists of an element's candidate triangles (or collider
    /// vertices) and of the collider edges already tested, reused from one
    /// skin element to the next: allocating and growing them per element
    /// took about a tenth of an in-loop pass.
    pub(super) static CANDIDATES: RefCell<Vec<u32>> = const { RefCell::new(Vec::new()) };
    pub(super) static SEEN: RefCell<Vec<u32>> = const { RefCell::new(Vec::new()) };
}

/// A thread's buffer, lent empty for one element's tests and handed back
/// when dropped. (Taken out of its cell rather than borrowed in place, so a
/// nested use on the same thread just gets a fresh list.)
pub(super) struct Scratch {
    list: Vec<u32>,
    home: &'static LocalKey<RefCell<Vec<u32>>>,
}

impl Scratch {
    pub(super) fn lend(home: &'static LocalKey<RefCell<Vec<u32>>>) -> Self {
        let mut list = home.with(|cell| std::mem::take(&mut *cell.borrow_mut()));
        list.clear();
        Scratch { list, home }
    }
}

impl Drop for Scratch {
    fn drop(&mut self) {
        let list = std::mem::take(&mut self.list);
        let _ = self.home.try_with(|cell| *cell.borrow_mut() = list);
    }
}

impl std::ops::Deref for Scratch {
    type Target = Vec<u32>;
    fn deref(&self) -> &Vec<u32> {
        &self.list
    }
}

impl std::ops::DerefMut for Scratch {
    fn deref_mut(&mut self) -> &mut Vec<u32> {
        &mut self.list
    }
}
