//! The output rules: atomic replacement, regular files only, links
//! followed, owner and mode kept, short temporaries, stale ones removed
//! unless held, and which targets are the same.

use super::*;
use std::io::Write;
#[cfg(unix)]
use std::os::unix::fs::{MetadataExt, PermissionsExt};

fn names(dir: &Path) -> Vec<String> {
    let mut v: Vec<String> = fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    v.sort();
    v
}

fn is_root() -> bool {
    #[cfg(unix)]
    {
        rustix::process::geteuid().is_root()
    }
    #[cfg(not(unix))]
    {
        false
    }
}

#[test]
fn a_failed_write_leaves_the_old_file_and_no_temporary() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("graph.g2o");
    fs::write(&path, "old").unwrap();
    let err = write(&path, |w| {
        w.write_all(b"partial")?;
        Err(io::Error::other("interrupted"))
    })
    .unwrap_err();
    assert!(matches!(err.problem, OutputProblem::Write(_)), "{err}");
    assert_eq!(
        err.to_string(),
        format!(
            "{}: interrupted (the file is left as it was)",
            path.display()
        )
    );
    assert_eq!(fs::read_to_string(&path).unwrap(), "old");
    assert_eq!(names(dir.path()), ["graph.g2o"]);
    write(&path, |w| w.write_all(b"new")).unwrap();
    assert_eq!(fs::read_to_string(&path).unwrap(), "new");
    assert_eq!(names(dir.path()), ["graph.g2o"]);
}

#[test]
#[cfg(unix)]
fn the_mode_is_kept_and_a_new_file_gets_what_the_shell_gives() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("graph.g2o");
    fs::write(&path, "old").unwrap();
    fs::set_permissions(&path, fs::Permissions::from_mode(0o4751)).unwrap();
    write(&path, |w| w.write_all(b"new")).unwrap();
    assert_eq!(fs::metadata(&path).unwrap().mode() & 0o7777, 0o4751);
    // A new file: 0666 less the umask, as File::create (and `>`) give.
    let reference = dir.path().join("reference");
    File::create(&reference).unwrap();
    let new = dir.path().join("new.g2o");
    write(&new, |w| w.write_all(b"x")).unwrap();
    assert_eq!(
        fs::metadata(&new).unwrap().mode() & 0o7777,
        fs::metadata(&reference).unwrap().mode() & 0o7777
    );
}

#[test]
#[cfg(unix)]
fn the_owner_is_kept_when_root() {
    if !is_root() {
        eprintln!("skipped: changing a file's owner needs root");
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("theirs.g2o");
    fs::write(&path, "old").unwrap();
    std::os::unix::fs::chown(&path, Some(4321), Some(4322)).unwrap();
    fs::set_permissions(&path, fs::Permissions::from_mode(0o2640)).unwrap();
    write(&path, |w| w.write_all(b"new")).unwrap();
    let meta = fs::metadata(&path).unwrap();
    assert_eq!((meta.uid(), meta.gid()), (4321, 4322));
    assert_eq!(meta.mode() & 0o7777, 0o2640, "set-gid kept after chown");
}

#[test]
fn a_name_of_255_bytes_works() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("g".repeat(251) + ".g2o");
    write(&path, |w| w.write_all(b"long")).unwrap();
    assert_eq!(fs::read_to_string(&path).unwrap(), "long");
    write(&path, |w| w.write_all(b"again")).unwrap();
    assert_eq!(fs::read_to_string(&path).unwrap(), "again");
}

#[test]
fn directories_and_missing_directories_are_refused_by_name() {
    let dir = tempfile::tempdir().unwrap();
    let err = write(dir.path(), |w| w.write_all(b"x")).unwrap_err();
    assert!(
        matches!(
            err.problem,
            OutputProblem::NotRegular {
                kind: FileKind::Directory,
                link: None
            }
        ),
        "{err}"
    );
    assert!(
        err.to_string()
            .starts_with(&format!("{}: is a directory", dir.path().display()))
    );
    let missing = dir.path().join("no/such/dir/out.g2o");
    let err = write(&missing, |w| w.write_all(b"x")).unwrap_err();
    assert!(
        matches!(err.problem, OutputProblem::Temporary { .. }),
        "{err}"
    );
    assert!(err.to_string().contains("no/such/dir"), "{err}");
    for empty in ["", "/", ".."] {
        let err = write(Path::new(empty), |_| Ok(())).unwrap_err();
        assert!(
            matches!(err.problem, OutputProblem::NoFileName),
            "{empty}: {err}"
        );
    }
}

#[test]
#[cfg(unix)]
fn fifos_sockets_and_devices_are_refused_and_left_alone() {
    use std::os::unix::fs::FileTypeExt;
    let dir = tempfile::tempdir().unwrap();
    let mut nodes: Vec<(PathBuf, FileKind)> = Vec::new();
    let fifo = dir.path().join("fifo");
    if std::process::Command::new("mkfifo")
        .arg(&fifo)
        .status()
        .is_ok_and(|s| s.success())
    {
        nodes.push((fifo, FileKind::Fifo));
    }
    let socket = dir.path().join("socket");
    let _listener = std::os::unix::net::UnixListener::bind(&socket).unwrap();
    nodes.push((socket, FileKind::Socket));
    if is_root() {
        // Our own copy of /dev/null (character device 1:3), never the real one.
        let null = dir.path().join("null");
        use rustix::fs::{CWD, FileType, Mode, makedev, mknodat};
        if mknodat(
            CWD,
            &null,
            FileType::CharacterDevice,
            Mode::from_raw_mode(0o666),
            makedev(1, 3),
        )
        .is_ok()
        {
            nodes.push((null, FileKind::CharDevice));
        }
    } else {
        eprintln!("note: the character-device case needs root (mknod)");
    }
    for (node, kind) in nodes {
        let before = fs::symlink_metadata(&node).unwrap().file_type();
        let err = write(&node, |w| w.write_all(b"x")).unwrap_err();
        assert!(
            matches!(err.problem, OutputProblem::NotRegular { kind: k, .. } if k == kind),
            "{err}"
        );
        assert!(
            err.to_string()
                .starts_with(&format!("{}: is {kind}", node.display())),
            "{err}"
        );
        // Through a link too: the link and the node stay.
        let link = dir.path().join(format!(
            "link-{}",
            node.file_name().unwrap().to_string_lossy()
        ));
        std::os::unix::fs::symlink(&node, &link).unwrap();
        let err = write(&link, |w| w.write_all(b"x")).unwrap_err();
        assert!(err.to_string().contains("is a symbolic link to"), "{err}");
        assert!(err.to_string().contains(&kind.to_string()), "{err}");
        let after = fs::symlink_metadata(&node).unwrap().file_type();
        assert_eq!(
            (
                before.is_fifo(),
                before.is_socket(),
                before.is_char_device()
            ),
            (after.is_fifo(), after.is_socket(), after.is_char_device())
        );
        assert!(
            fs::symlink_metadata(&link)
                .unwrap()
                .file_type()
                .is_symlink()
        );
    }
}

#[test]
#[cfg(unix)]
fn links_are_written_through_and_dangling_ones_refused() {
    let dir = tempfile::tempdir().unwrap();
    fs::create_dir(dir.path().join("real")).unwrap();
    let file = dir.path().join("real/graph.g2o");
    fs::write(&file, "old").unwrap();
    let link = dir.path().join("link.g2o");
    std::os::unix::fs::symlink("real/graph.g2o", &link).unwrap();
    let chain = dir.path().join("chain.g2o");
    std::os::unix::fs::symlink("link.g2o", &chain).unwrap();
    write(&chain, |w| w.write_all(b"new")).unwrap();
    assert_eq!(fs::read_to_string(&file).unwrap(), "new");
    for l in [&link, &chain] {
        assert!(fs::symlink_metadata(l).unwrap().file_type().is_symlink());
    }
    // The temporary was made beside the file, and is gone.
    assert_eq!(names(&dir.path().join("real")), ["graph.g2o"]);
    assert_eq!(names(dir.path()), ["chain.g2o", "link.g2o", "real"]);
    let dangling = dir.path().join("dangling.g2o");
    std::os::unix::fs::symlink("nowhere/x.g2o", &dangling).unwrap();
    let err = write(&dangling, |w| w.write_all(b"x")).unwrap_err();
    assert_eq!(
        err.to_string(),
        format!(
            "{}: is a symbolic link to nowhere/x.g2o, which does not exist; pgo writes through a link only to an existing regular file",
            dangling.display()
        )
    );
    assert!(!dir.path().join("nowhere").exists());
}

#[test]
#[cfg(unix)]
fn leftovers_nobody_holds_are_removed_and_held_ones_kept() {
    use rustix::fs::{FlockOperation, flock};
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("graph.g2o");
    let stale = dir.path().join(".pgo-AbCd1234.tmp");
    let held = dir.path().join(".pgo-HeLd5678.tmp");
    let not_ours = [
        ".pgo-short.tmp",
        ".pgo-AbCd1234.tmpx",
        ".graph.g2o.pgo-tmp-4294967",
    ];
    fs::write(&stale, "partial").unwrap();
    fs::write(&held, "being written").unwrap();
    let holder = File::open(&held).unwrap();
    flock(&holder, FlockOperation::NonBlockingLockExclusive).unwrap();
    for n in not_ours {
        fs::write(dir.path().join(n), "x").unwrap();
    }
    // A link under our pattern is not followed, its target not removed.
    let victim = dir.path().join("victim");
    fs::write(&victim, "precious").unwrap();
    std::os::unix::fs::symlink(&victim, dir.path().join(".pgo-LiNk0000.tmp")).unwrap();
    write(&path, |w| w.write_all(b"new")).unwrap();
    assert!(!stale.exists(), "a stale temporary stayed");
    assert!(held.exists(), "a held temporary was removed");
    assert_eq!(fs::read_to_string(&victim).unwrap(), "precious");
    let left = names(dir.path());
    for n in not_ours.iter().chain(&[".pgo-LiNk0000.tmp"]) {
        assert!(left.contains(&n.to_string()), "{n} removed: {left:?}");
    }
    // Released, it is a leftover like any other. A process another test
    // spawns at that moment can hold a copy of the descriptor (and so the
    // lock) between its fork and its exec: a few writes are allowed.
    drop(holder);
    for _ in 0..50 {
        write(&path, |w| w.write_all(b"newer")).unwrap();
        if !held.exists() {
            break;
        }
        std::thread::sleep(std::time::Duration::from_millis(20));
    }
    assert!(!held.exists());
}

#[test]
fn temporary_names_are_short_and_exact() {
    assert!(temporary::is_temporary_name(".pgo-AbCd1234.tmp"));
    for n in [
        ".pgo-AbCd123.tmp",
        ".pgo-AbCd-234.tmp",
        "pgo-AbCd1234.tmp",
        ".pgo-AbCd1234.tm",
    ] {
        assert!(!temporary::is_temporary_name(n), "{n}");
    }
}

#[test]
#[cfg(unix)]
fn same_targets_are_told_through_links_dots_and_hard_links() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    fs::create_dir(d.join("sub")).unwrap();
    let a = d.join("a.g2o");
    fs::write(&a, "x").unwrap();
    std::os::unix::fs::symlink(&a, d.join("link.g2o")).unwrap();
    fs::hard_link(&a, d.join("hard.g2o")).unwrap();
    let target = |p: &Path| Target::resolve(p).unwrap();
    let ta = target(&a);
    for same in ["sub/../a.g2o", "link.g2o", "hard.g2o"] {
        assert!(ta.same_as(&target(&d.join(same))), "{same}");
        assert!(target(&d.join(same)).is_file(&a), "{same}");
    }
    assert!(!ta.same_as(&target(&d.join("b.g2o"))));
    // Files still to be made: the same directory and name.
    assert!(target(&d.join("new.g2o")).same_as(&target(&d.join("sub/../new.g2o"))));
    assert!(!target(&d.join("new.g2o")).same_as(&target(&d.join("sub/new.g2o"))));
    // stdout is stdout; stdin is no file.
    let dash = Path::new("-");
    assert!(target(dash).same_as(&target(dash)));
    assert!(!target(dash).same_as(&ta));
    assert!(!ta.is_file(dash));
    assert!(!target(&d.join("new.g2o")).is_file(&a));
}

#[test]
fn problems_keep_their_io_kind() {
    let e = OutputError::new(
        Path::new("-"),
        OutputProblem::Stdout(io::ErrorKind::BrokenPipe.into()),
    );
    assert!(e.is_broken_pipe());
    assert!(e.to_string().starts_with("stdout: "), "{e}");
    let io = OutputError::new(
        Path::new("x"),
        OutputProblem::NotRegular {
            kind: FileKind::Fifo,
            link: None,
        },
    )
    .into_io();
    assert_eq!(io.kind(), io::ErrorKind::InvalidInput);
    assert_eq!(
        io.to_string(),
        "is a FIFO (named pipe); pgo writes only regular files (use - for stdout)"
    );
}
