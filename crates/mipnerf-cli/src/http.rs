//! The viewer's HTTP/1.1, as little of it as the viewer needs: one thread per connection, one
//! request per connection (every answer says `Connection: close`), the request's head parsed by
//! `httparse` from at most [`MAX_HEAD_BYTES`] read within [`HEAD_TIMEOUT`], and no body read.
//! Owning the connection is what lets the viewer bound what a client can make it hold (a
//! 100 MB header is refused at 16 KiB, answered 431) and notice a client that has gone away
//! ([`Request::client_gone`]), so that its frame is not rendered for nobody.

use std::io::{Read, Write};
use std::net::{TcpListener, TcpStream};
use std::time::{Duration, Instant};

/// The most bytes a request's head (request line and headers) may take.
pub const MAX_HEAD_BYTES: usize = 16 * 1024;
/// The most header lines a request may have.
pub const MAX_HEADERS: usize = 64;
/// How long a client may take to send its request's head.
pub const HEAD_TIMEOUT: Duration = Duration::from_secs(10);

/// One request's head, and the connection to answer on.
pub struct Request {
    method: String,
    url: String,
    headers: Vec<(String, String)>,
    stream: TcpStream,
}

impl Request {
    /// The method (`GET`, ...).
    pub fn method(&self) -> &str {
        &self.method
    }

    /// The request target: path and query.
    pub fn url(&self) -> &str {
        &self.url
    }

    /// The value of the header `name` (any case), if the request has it.
    pub fn header(&self, name: &str) -> Option<&str> {
        self.headers.iter().find(|(k, _)| k.eq_ignore_ascii_case(name)).map(|(_, v)| v.as_str())
    }

    /// Answers with `code` and `body`, then closes the connection. A client that has gone is
    /// no error: there is nobody to tell.
    pub fn respond(mut self, code: u16, content_type: &str, body: &[u8]) {
        write_response(&mut self.stream, code, content_type, body);
    }

    /// The connection, to write a response of one's own (a stream of events).
    pub fn into_stream(self) -> TcpStream {
        self.stream
    }

    /// Whether the client has closed its side of the connection (it sends nothing after its
    /// request, so anything but "no data yet" from a look at the socket means it is gone).
    pub fn client_gone(&self) -> bool {
        gone(&self.stream)
    }
}

/// Whether the peer of `stream` has closed the connection (see [`Request::client_gone`]).
pub fn gone(stream: &TcpStream) -> bool {
    if stream.set_nonblocking(true).is_err() {
        return true;
    }
    let mut byte = [0u8; 1];
    let closed = match stream.peek(&mut byte) {
        Ok(0) => true,
        Ok(_) => false,
        Err(e) => e.kind() != std::io::ErrorKind::WouldBlock,
    };
    let _ = stream.set_nonblocking(false);
    closed
}

/// Writes a whole response (`Connection: close`) to `stream`; a client that has gone is no error.
fn write_response(stream: &mut TcpStream, code: u16, content_type: &str, body: &[u8]) {
    let head = format!(
        "HTTP/1.1 {code} {}\r\nContent-Type: {content_type}\r\nContent-Length: {}\r\nCache-Control: no-cache\r\n\
         Connection: close\r\n\r\n",
        reason(code),
        body.len()
    );
    let _ = stream.write_all(head.as_bytes()).and_then(|()| stream.write_all(body)).and_then(|()| stream.flush());
}

/// The reason phrase of the codes the viewer answers with.
fn reason(code: u16) -> &'static str {
    match code {
        200 => "OK",
        400 => "Bad Request",
        403 => "Forbidden",
        404 => "Not Found",
        405 => "Method Not Allowed",
        408 => "Request Timeout",
        431 => "Request Header Fields Too Large",
        503 => "Service Unavailable",
        _ => "Internal Server Error",
    }
}

/// Reads the head of the request on `stream`. A head that is malformed, too large or too slow is
/// answered here (400, 431, 408) and gives `None`.
pub fn read_request(mut stream: TcpStream) -> Option<Request> {
    let start = Instant::now();
    let mut buf = vec![0u8; MAX_HEAD_BYTES];
    let mut len = 0;
    let refuse = |mut stream: TcpStream, code: u16, why: &str| {
        write_response(&mut stream, code, "text/plain", why.as_bytes());
        None
    };
    loop {
        let left = HEAD_TIMEOUT.saturating_sub(start.elapsed());
        if left.is_zero() || stream.set_read_timeout(Some(left)).is_err() {
            return refuse(stream, 408, "the request's head did not arrive in time");
        }
        let n = match stream.read(&mut buf[len..]) {
            Ok(0) => return None,
            Ok(n) => n,
            Err(e) if matches!(e.kind(), std::io::ErrorKind::WouldBlock | std::io::ErrorKind::TimedOut) => {
                return refuse(stream, 408, "the request's head did not arrive in time");
            }
            Err(_) => return None,
        };
        len += n;
        let mut headers = [httparse::EMPTY_HEADER; MAX_HEADERS];
        let mut parsed = httparse::Request::new(&mut headers);
        match parsed.parse(&buf[..len]) {
            Ok(httparse::Status::Complete(_)) => {
                let method = parsed.method.unwrap_or_default().to_string();
                let url = parsed.path.unwrap_or_default().to_string();
                let headers = parsed
                    .headers
                    .iter()
                    .map(|h| (h.name.to_string(), String::from_utf8_lossy(h.value).trim().to_string()))
                    .collect();
                let _ = stream.set_read_timeout(None);
                return Some(Request { method, url, headers, stream });
            }
            Ok(httparse::Status::Partial) if len < MAX_HEAD_BYTES => {}
            Ok(httparse::Status::Partial) => {
                return refuse(stream, 431, "the request's head is larger than 16 KiB");
            }
            Err(httparse::Error::TooManyHeaders) => return refuse(stream, 431, "more than 64 header lines"),
            Err(e) => return refuse(stream, 400, &format!("not an HTTP request: {e}")),
        }
    }
}

/// Binds `host:port`.
///
/// # Errors
/// An address that cannot be bound.
pub fn bind(host: &str, port: u16) -> std::io::Result<TcpListener> {
    TcpListener::bind((host, port))
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]
    use super::*;

    /// Sends `bytes` to a fresh listener's connection and returns what `read_request` made of it
    /// (method, url, one header) and what the client was answered.
    fn exchange(bytes: &[u8]) -> (Option<(String, String, Option<String>)>, String) {
        let listener = TcpListener::bind("127.0.0.1:0").unwrap();
        let addr = listener.local_addr().unwrap();
        let bytes = bytes.to_vec();
        let client = std::thread::spawn(move || {
            let mut s = TcpStream::connect(addr).unwrap();
            // A refusal may close the connection before everything is sent.
            let _ = s.write_all(&bytes);
            let _ = s.shutdown(std::net::Shutdown::Write);
            let mut answer = String::new();
            let _ = s.read_to_string(&mut answer);
            answer
        });
        let (stream, _) = listener.accept().unwrap();
        let got = read_request(stream).map(|r| {
            let host = r.header("host").map(str::to_string);
            let parts = (r.method().to_string(), r.url().to_string(), host);
            r.respond(200, "text/plain", b"ok");
            parts
        });
        (got, client.join().unwrap())
    }

    #[test]
    fn a_request_head_is_parsed_and_bounded() {
        let (got, answer) = exchange(b"GET /api/info?x=1 HTTP/1.1\r\nHOST: 127.0.0.1:8\r\n\r\n");
        assert_eq!(got, Some(("GET".into(), "/api/info?x=1".into(), Some("127.0.0.1:8".into()))));
        assert!(answer.starts_with("HTTP/1.1 200 OK\r\n") && answer.ends_with("\r\n\r\nok"), "{answer}");
        let huge = format!("GET / HTTP/1.1\r\nX-Big: {}\r\n\r\n", "a".repeat(100_000));
        let (got, answer) = exchange(huge.as_bytes());
        assert!(got.is_none() && answer.starts_with("HTTP/1.1 431"), "{answer}");
        let many: String = (0..100).map(|i| format!("X-{i}: 1\r\n")).collect();
        let (got, answer) = exchange(format!("GET / HTTP/1.1\r\n{many}\r\n").as_bytes());
        assert!(got.is_none() && answer.starts_with("HTTP/1.1 431"), "{answer}");
        let (got, answer) = exchange(b"\x16\x03\x01 not http\r\n\r\n");
        assert!(got.is_none() && answer.starts_with("HTTP/1.1 400"), "{answer}");
    }
}
