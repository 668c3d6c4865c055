//! Panics that are expected and turned into errors: a third-party decoder
//! that panics on corrupt data, a plugin's op. [`catch_quietly`] catches one
//! and returns its message; with [`install_hook`] in place (the CLI installs
//! it) such a caught panic is logged at debug level instead of printing the
//! "thread panicked" text and a backtrace, which a user would take for a crash
//! even though the run goes on and names the file. Other panics print as
//! before.

use std::cell::Cell;
use std::panic::{AssertUnwindSafe, catch_unwind};

thread_local! {
    static EXPECTED: Cell<u32> = const { Cell::new(0) };
}

/// Runs `f`, turning a panic into `Err(message)`.
pub fn catch_quietly<T>(f: impl FnOnce() -> T) -> Result<T, String> {
    EXPECTED.with(|e| e.set(e.get() + 1));
    let result = catch_unwind(AssertUnwindSafe(f));
    EXPECTED.with(|e| e.set(e.get() - 1));
    result.map_err(|payload| message(payload.as_ref()))
}

/// The text of a panic's payload.
pub fn message(payload: &(dyn std::any::Any + Send)) -> String {
    payload
        .downcast_ref::<&str>()
        .map(|s| s.to_string())
        .or_else(|| payload.downcast_ref::<String>().cloned())
        .unwrap_or_else(|| "a panic without a message".into())
}

/// Installs a panic hook that keeps panics inside [`catch_quietly`] quiet
/// (logged at debug level) and passes every other panic to the hook that was
/// in place.
pub fn install_hook() {
    let previous = std::panic::take_hook();
    std::panic::set_hook(Box::new(move |info| {
        if EXPECTED.with(|e| e.get()) > 0 {
            tracing::debug!("caught panic: {info}");
        } else {
            previous(info);
        }
    }));
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_caught_panic_becomes_its_message() {
        assert_eq!(catch_quietly(|| 7), Ok(7));
        let e = catch_quietly(|| -> u8 { panic!("bad frame {}", 3) }).unwrap_err();
        assert_eq!(e, "bad frame 3");
        // The nesting count is back to zero after a panic.
        assert_eq!(EXPECTED.with(|e| e.get()), 0);
    }
}
