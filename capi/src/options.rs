//! The options of the optimisation: `PgoOptions`, set by the command
//! line's flag names.

use crate::status::{PgoStatus, borrow_mut, out_ptr, status, text, value};
use pgo::Options;

/// The options of `pgo_graph_optimize` and `pgo_graph_update` (opaque):
/// the gate, the robust back end, the solver and the χ² test, each set by
/// the long flag `pgo optimize` spells it with.
///
/// Made by `pgo_options_new`, owned by the caller, freed by
/// `pgo_options_free`. Passing NULL to `pgo_graph_optimize` or
/// `pgo_graph_update` means the defaults.
pub struct PgoOptions {
    pub(crate) options: Options,
}

/// Makes options with every default (those of `pgo optimize` without
/// flags) and stores them at `*out`; free them with `pgo_options_free`.
///
/// Errors: `PGO_ERR_INVALID_ARGUMENT` for a NULL `out`.
///
/// # Safety
/// `out` is NULL or points to writable storage for a pointer.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn pgo_options_new(out: *mut *mut PgoOptions) -> PgoStatus {
    status(|| {
        let slot = out_ptr(out, "out")?;
        let options = Box::new(PgoOptions {
            options: Options::default(),
        });
        // SAFETY: writable, by the caller's contract.
        unsafe { *slot = Box::into_raw(options) };
        Ok(())
    })
}

/// Sets one option by its command-line long flag without the `--` (`gate`,
/// `robust`, `robust-c`, `alpha`, `threads`, `expert`, ...; `-` and `_`
/// are the same; the message of `PGO_ERR_UNKNOWN_OPTION` lists them all)
/// from its value as text, parsed as the command line parses it
/// (`pgo optimize --help` documents them). On failure the options are
/// unchanged.
///
/// Errors: `PGO_ERR_UNKNOWN_OPTION` (the message lists the names),
/// `PGO_ERR_INVALID_OPTION` (the message names the option and the value),
/// `PGO_ERR_INVALID_ARGUMENT`.
///
/// # Safety
/// `options` is NULL or live options nothing else uses during the call;
/// `name` and `value` are NULL or NUL-terminated strings.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn pgo_options_set(
    options: *mut PgoOptions,
    name: *const std::ffi::c_char,
    value: *const std::ffi::c_char,
) -> PgoStatus {
    status(|| {
        // SAFETY: the caller's contract.
        let (options, name, value) = unsafe {
            (
                borrow_mut(options, "options")?,
                text(name, "name")?,
                text(value, "value")?,
            )
        };
        Ok(options.options.set(name, value)?)
    })
}

/// Frees options made by `pgo_options_new`. NULL is allowed and does
/// nothing.
///
/// # Safety
/// `options` is NULL or options from this API not yet freed, which nothing
/// uses any more.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn pgo_options_free(options: *mut PgoOptions) {
    if !options.is_null() {
        value((), || {
            // SAFETY: made by Box::into_raw and not yet freed, by the contract.
            drop(unsafe { Box::from_raw(options) });
            Ok(())
        });
    }
}
