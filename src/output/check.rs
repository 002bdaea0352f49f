//! The check of a command's files before anything is read or written: no
//! output is an input, no two outputs are the same, stdin is read once.

use super::{OutputError, Target};
use std::path::{Path, PathBuf};

/// Why a command's files are refused.
#[derive(Debug, thiserror::Error)]
pub enum CheckError {
    /// An output cannot be written by the rules of [`super`].
    #[error(transparent)]
    Output(#[from] OutputError),
    /// An output is one of the inputs.
    #[error(
        "{}: the output is the input file {}; pgo overwrites its input only with --in-place",
        output.display(),
        input.display()
    )]
    IsInput {
        /// The output as given.
        output: PathBuf,
        /// The input it is.
        input: PathBuf,
    },
    /// Two outputs are the same file.
    #[error(
        "{}: {option} is the same file as {first} ({}); each output needs a file of its own",
        path.display(),
        first_path.display()
    )]
    SameFile {
        /// The option of the second output.
        option: String,
        /// Its path.
        path: PathBuf,
        /// The option of the first.
        first: String,
        /// Its path.
        first_path: PathBuf,
    },
    /// Two outputs are both stdout.
    #[error("{first} and {option} both write to stdout (-)")]
    BothStdout {
        /// The first option.
        first: String,
        /// The second.
        option: String,
    },
    /// Two inputs are both stdin.
    #[error("stdin (-) can be read only once: give the other inputs as files")]
    StdinTwice,
}

/// Checks the files a command reads (`inputs`, `-`: stdin) and writes
/// (`outputs`, each with the option that names it) before any is opened:
/// every output must be writable by the rules of [`super`] (resolved only:
/// a FIFO is not opened), none may be an input (through links, `..` and
/// hard links too; `--in-place` passes its input as an output and not as an
/// input), no two outputs may be the same file or both stdout, and at most
/// one input may be stdin.
pub fn check_files(inputs: &[&Path], outputs: &[(&str, &Path)]) -> Result<(), CheckError> {
    if inputs.iter().filter(|p| p.as_os_str() == "-").count() > 1 {
        return Err(CheckError::StdinTwice);
    }
    let mut targets: Vec<(&str, &Path, Target)> = Vec::new();
    for &(option, path) in outputs {
        let target = Target::resolve(path)?;
        if let Some(input) = inputs.iter().find(|i| target.is_file(i)) {
            return Err(CheckError::IsInput {
                output: path.to_owned(),
                input: input.to_path_buf(),
            });
        }
        if let Some((first, first_path, _)) = targets.iter().find(|(_, _, t)| t.same_as(&target)) {
            return Err(if matches!(target, Target::Stdout) {
                CheckError::BothStdout {
                    first: (*first).to_owned(),
                    option: option.to_owned(),
                }
            } else {
                CheckError::SameFile {
                    option: option.to_owned(),
                    path: path.to_owned(),
                    first: (*first).to_owned(),
                    first_path: first_path.to_path_buf(),
                }
            });
        }
        targets.push((option, path, target));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn outputs_that_are_inputs_or_each_other_are_named() {
        let dir = tempfile::tempdir().unwrap();
        let input = dir.path().join("in.g2o");
        std::fs::write(&input, "x").unwrap();
        let out = dir.path().join("out.g2o");
        let dash = Path::new("-");
        let err = check_files(&[&input], &[("-o", &input)]).unwrap_err();
        assert!(matches!(err, CheckError::IsInput { .. }), "{err}");
        assert!(err.to_string().contains("--in-place"), "{err}");
        let err = check_files(&[], &[("-o", &out), ("--labels", &out)]).unwrap_err();
        assert_eq!(
            err.to_string(),
            format!(
                "{}: --labels is the same file as -o ({}); each output needs a file of its own",
                out.display(),
                out.display()
            )
        );
        let err = check_files(&[], &[("-o", dash), ("--truth", dash)]).unwrap_err();
        assert_eq!(err.to_string(), "-o and --truth both write to stdout (-)");
        let err = check_files(&[dash, dash], &[]).unwrap_err();
        assert!(matches!(err, CheckError::StdinTwice));
        let err = check_files(&[], &[("-o", dir.path())]).unwrap_err();
        assert!(matches!(err, CheckError::Output(_)), "{err}");
        // stdin in and stdout out, a new file: fine.
        check_files(&[dash, &input], &[("-o", dash), ("--labels", &out)]).unwrap();
    }
}
