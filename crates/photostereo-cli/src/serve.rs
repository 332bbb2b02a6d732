//! A minimal static HTTP/1.1 server for a view folder, bound to 127.0.0.1 only: GET and HEAD of
//! files under the root (`/` is `index.html`), nothing else. Paths with `..`, absolute or
//! hidden components are refused, and so is any request outside the root after resolving links.
//! One thread per connection, `Connection: close`.

use photostereo::{Error, Result};
use std::io::{BufRead, BufReader, Read, Write};
use std::net::{Ipv4Addr, SocketAddr, TcpListener, TcpStream};
use std::path::{Path, PathBuf};
use std::time::Duration;

/// A bound server; [`Server::run`] serves until the process ends.
pub struct Server {
    listener: TcpListener,
    root: PathBuf,
}

impl Server {
    /// Binds 127.0.0.1:`port` (0 = a free port chosen by the system) to serve `root`.
    pub fn bind(root: &Path, port: u16) -> Result<Server> {
        let root = std::fs::canonicalize(root).map_err(|e| Error::io(root, e))?;
        let listener = TcpListener::bind((Ipv4Addr::LOCALHOST, port))
            .map_err(|e| Error::invalid(format!("cannot listen on 127.0.0.1:{port}: {e}")))?;
        Ok(Server { listener, root })
    }

    /// The address listened on.
    pub fn addr(&self) -> SocketAddr {
        self.listener
            .local_addr()
            .expect("a bound listener has an address")
    }

    /// The page's address, `http://127.0.0.1:PORT/`.
    pub fn url(&self) -> String {
        format!("http://{}/", self.addr())
    }

    /// Serves connections forever (or until accepting fails).
    pub fn run(self) -> Result<()> {
        for stream in self.listener.incoming() {
            let stream = match stream {
                Ok(s) => s,
                Err(_) => continue,
            };
            let root = self.root.clone();
            std::thread::spawn(move || {
                let _ = handle(stream, &root);
            });
        }
        Ok(())
    }
}

fn content_type(path: &Path) -> &'static str {
    match path
        .extension()
        .and_then(|e| e.to_str())
        .unwrap_or("")
        .to_ascii_lowercase()
        .as_str()
    {
        "html" | "htm" => "text/html; charset=utf-8",
        "js" => "text/javascript; charset=utf-8",
        "json" => "application/json",
        "css" => "text/css; charset=utf-8",
        "png" => "image/png",
        "jpg" | "jpeg" => "image/jpeg",
        "svg" => "image/svg+xml",
        "txt" => "text/plain; charset=utf-8",
        "dzi" | "xml" => "application/xml",
        _ => "application/octet-stream",
    }
}

fn percent_decode(s: &str) -> Option<String> {
    let b = s.as_bytes();
    let mut out = Vec::with_capacity(b.len());
    let mut i = 0;
    while i < b.len() {
        if b[i] == b'%' {
            let hex = std::str::from_utf8(b.get(i + 1..i + 3)?).ok()?;
            out.push(u8::from_str_radix(hex, 16).ok()?);
            i += 3;
        } else {
            out.push(b[i]);
            i += 1;
        }
    }
    String::from_utf8(out).ok()
}

/// The file under `root` that `target` (the request's path) names, if it may be served.
pub fn resolve(root: &Path, target: &str) -> Option<PathBuf> {
    let path = target.split(['?', '#']).next()?;
    let path = percent_decode(path)?;
    let mut out = root.to_path_buf();
    for part in path.split('/').filter(|p| !p.is_empty()) {
        if part.starts_with('.') || part.contains('\\') || part.contains('\0') {
            return None;
        }
        out.push(part);
    }
    if out.is_dir() {
        out.push("index.html");
    }
    let real = std::fs::canonicalize(&out).ok()?;
    (real.starts_with(root) && real.is_file()).then_some(real)
}

fn respond(s: &mut TcpStream, status: &str, ctype: &str, body: &[u8], head: bool) -> Result<()> {
    let header = format!(
        "HTTP/1.1 {status}\r\nContent-Type: {ctype}\r\nContent-Length: {}\r\n\
         Cache-Control: no-cache\r\nX-Content-Type-Options: nosniff\r\nConnection: close\r\n\r\n",
        body.len()
    );
    let io = |e| Error::invalid(format!("http: {e}"));
    s.write_all(header.as_bytes()).map_err(io)?;
    if !head {
        s.write_all(body).map_err(io)?;
    }
    s.flush().map_err(io)
}

fn handle(mut stream: TcpStream, root: &Path) -> Result<()> {
    let _ = stream.set_read_timeout(Some(Duration::from_secs(10)));
    let mut reader = BufReader::new(
        stream
            .try_clone()
            .map_err(|e| Error::invalid(e.to_string()))?,
    );
    let mut line = String::new();
    reader
        .by_ref()
        .take(8192)
        .read_line(&mut line)
        .map_err(|e| Error::invalid(format!("http: {e}")))?;
    // Skip the headers (bounded).
    let mut seen = 0usize;
    loop {
        let mut h = String::new();
        let n = reader
            .by_ref()
            .take(8192)
            .read_line(&mut h)
            .map_err(|e| Error::invalid(format!("http: {e}")))?;
        seen += n;
        if n == 0 || h == "\r\n" || h == "\n" || seen > 65536 {
            break;
        }
    }
    let mut parts = line.split_whitespace();
    let (method, target) = (parts.next().unwrap_or(""), parts.next().unwrap_or(""));
    let head = method == "HEAD";
    if method != "GET" && !head {
        return respond(
            &mut stream,
            "405 Method Not Allowed",
            "text/plain",
            b"only GET and HEAD\n",
            false,
        );
    }
    match resolve(root, target) {
        Some(p) => match std::fs::read(&p) {
            Ok(body) => respond(&mut stream, "200 OK", content_type(&p), &body, head),
            Err(_) => respond(
                &mut stream,
                "404 Not Found",
                "text/plain",
                b"not found\n",
                head,
            ),
        },
        None => respond(
            &mut stream,
            "404 Not Found",
            "text/plain",
            b"not found\n",
            head,
        ),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn serves_files_under_the_root_only() {
        let dir = tempfile::tempdir().unwrap();
        let root = dir.path().join("site");
        std::fs::create_dir_all(root.join("view")).unwrap();
        std::fs::write(root.join("index.html"), "<p>hi</p>").unwrap();
        std::fs::write(root.join("view/a.js"), "x").unwrap();
        std::fs::write(dir.path().join("secret.txt"), "no").unwrap();
        let server = Server::bind(&root, 0).unwrap();
        let addr = server.addr();
        assert!(addr.ip().is_loopback());
        std::thread::spawn(move || server.run());
        let get = |path: &str| {
            let mut s = TcpStream::connect(addr).unwrap();
            s.set_read_timeout(Some(Duration::from_secs(5))).unwrap();
            write!(s, "GET {path} HTTP/1.1\r\nHost: x\r\n\r\n").unwrap();
            let mut out = String::new();
            s.read_to_string(&mut out).unwrap();
            out
        };
        let r = get("/");
        assert!(
            r.starts_with("HTTP/1.1 200") && r.ends_with("<p>hi</p>"),
            "{r}"
        );
        assert!(r.contains("text/html"));
        assert!(get("/view/a.js").contains("text/javascript"));
        assert!(get("/view/a%2Ejs").starts_with("HTTP/1.1 200"));
        for bad in [
            "/../secret.txt",
            "/view/../../secret.txt",
            "/%2e%2e/secret.txt",
            "/nope",
        ] {
            assert!(get(bad).starts_with("HTTP/1.1 404"), "{bad}");
        }
    }
}
