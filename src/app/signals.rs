//! The clean interruption of a run by SIGINT / SIGTERM / SIGUSR1 (what `mpirun` forwards to every rank
//! of a job without ending it): [`install_handlers`] makes the first signal set a
//! flag that the time loop reads at every stop ([`interrupted`]; the run then writes a checkpoint and
//! summary.json with `"status": "interrupted"` and exits with 128 + the signal number); a second signal
//! ends the process at once (`_exit`, same code), leaving at most a `.tmp` checkpoint behind.

use crate::error::{Error, Result};
use std::sync::atomic::{AtomicI32, AtomicUsize, Ordering};

static SIGNALS: AtomicUsize = AtomicUsize::new(0);
static LAST_SIGNAL: AtomicI32 = AtomicI32::new(0);

extern "C" fn on_signal(sig: libc::c_int) {
    // Only async-signal-safe work here: atomics and `_exit`.
    if SIGNALS.fetch_add(1, Ordering::SeqCst) >= 1 {
        // SAFETY: `_exit` is async-signal-safe.
        unsafe { libc::_exit(128 + sig) };
    }
    LAST_SIGNAL.store(sig, Ordering::SeqCst);
}

/// Installs the SIGINT / SIGTERM / SIGUSR1 handlers of `blockflow run`: the first signal asks the run to
/// stop at the next stop of the time loop ([`interrupted`]) with a checkpoint, a second one ends the
/// process at once.
pub fn install_handlers() -> Result<()> {
    for sig in [libc::SIGINT, libc::SIGTERM, libc::SIGUSR1] {
        // SAFETY: a zeroed sigaction is valid; the handler only touches atomics and calls `_exit`.
        let r = unsafe {
            let mut sa: libc::sigaction = std::mem::zeroed();
            sa.sa_sigaction = on_signal as extern "C" fn(libc::c_int) as libc::sighandler_t;
            sa.sa_flags = libc::SA_RESTART;
            libc::sigemptyset(&mut sa.sa_mask);
            libc::sigaction(sig, &sa, std::ptr::null_mut())
        };
        if r != 0 {
            return Err(Error::Io(format!(
                "cannot install the handler of signal {sig}: {}",
                std::io::Error::last_os_error()
            )));
        }
    }
    Ok(())
}

/// The signal that asked the run to stop, if one did (SIGINT = 2, SIGUSR1 = 10, SIGTERM = 15).
pub fn interrupted() -> Option<i32> {
    if SIGNALS.load(Ordering::SeqCst) > 0 {
        Some(LAST_SIGNAL.load(Ordering::SeqCst))
            .filter(|&s| s > 0)
            .or(Some(libc::SIGTERM))
    } else {
        None
    }
}
