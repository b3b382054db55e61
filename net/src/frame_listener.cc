#include "concord/net/frame_listener.h"

#include <spdlog/spdlog.h>

#include <atomic>
#include <boost/asio.hpp>
#include <deque>
#include <map>
#include <mutex>
#include <stdexcept>

#include "concord/net/host_port.h"
#include "concord/net/frame_codec.h"
#include "concord/net/log_limiter.h"
#include "concord/net/secure_channel.h"
#include "concord/v1/concord.pb.h"

namespace concord::net {

namespace {

namespace asio = boost::asio;
using tcp = asio::ip::tcp;
using Clock = std::chrono::steady_clock;
using ErrorCode = boost::system::error_code;


}  // namespace

std::vector<std::string> FrameListenerOptions::validate() const {
  std::vector<std::string> problems;
  ErrorCode error;
  asio::ip::make_address(listen_address, error);
  if (error) problems.push_back("listen_address: '" + listen_address + "' is not an IP address");
  if (max_frame_bytes < 1024 || max_frame_bytes > (std::size_t{1} << 30))
    problems.push_back("max_frame_bytes: " + std::to_string(max_frame_bytes) +
                       " is outside [1024, 1073741824]");
  if (idle_timeout.count() < 0)
    problems.push_back("idle_timeout: " + std::to_string(idle_timeout.count()) + " ms is negative");
  if (max_connections == 0) problems.push_back("max_connections: must be at least 1");
  if (busy_retry.count() <= 0) problems.push_back("busy_retry: must be positive");
  return problems;
}

class FrameListener::Impl : public std::enable_shared_from_this<FrameListener::Impl> {
 public:
  class Connection;

  Impl(asio::io_context& io, FrameListenerOptions options)
      : strand_(asio::make_strand(io)),
        options_(std::move(options)),
        acceptor_(strand_),
        idle_timer_(strand_) {}

  void start();
  void stop(bool detach = false);
  std::uint16_t port() const { return port_.load(); }
  FrameListenerCounters counters() const {
    FrameListenerCounters counters;
    {
      std::lock_guard lock(counters_mutex_);
      counters = counters_;
    }
    counters.log_lines_suppressed = log_limiter.suppressed_total();
    return counters;
  }
  LogLimiter log_limiter;

  EnvelopeHandler envelope_handler;
  CloseHandler close_handler;

  // Called by connections, on the strand.
  /// False: the handler is busy; offer the envelope again later.
  bool on_envelope(const Connection& connection, const v1::Envelope& envelope);
  void on_closed(const Connection& connection, const std::string& reason);
  void on_frame_error(const FrameError& error);
  template <class Function>
  void update_counters(Function&& function) {
    std::lock_guard lock(counters_mutex_);
    function(counters_);
  }
  const FrameListenerOptions& options() const { return options_; }

 private:
  void do_accept();
  void arm_idle_check();

  asio::strand<asio::io_context::executor_type> strand_;
  const FrameListenerOptions options_;
  std::atomic<bool> start_called_{false};
  std::atomic<std::uint16_t> port_{0};
  tcp::acceptor acceptor_;
  asio::steady_timer idle_timer_;
  bool stopping_ = false;
  std::uint64_t next_id_ = 1;
  std::map<std::uint64_t, std::weak_ptr<Connection>> connections_;
  mutable std::mutex counters_mutex_;
  FrameListenerCounters counters_;
};

class FrameListener::Impl::Connection : public std::enable_shared_from_this<Connection> {
 public:
  Connection(std::shared_ptr<Impl> listener, std::uint64_t id, tcp::socket socket,
             std::string remote)
      : id(id),
        remote(std::move(remote)),
        last_received(Clock::now()),
        listener_(std::move(listener)),
        socket_(std::move(socket)),
        decoder_(FrameDecoderOptions{listener_->options().max_frame_bytes,
                                     listener_->options().team.empty()
                                         ? std::nullopt
                                         : std::optional(listener_->options().team)}),
        buffer_(kReadChunkBytes),
        retry_timer_(socket_.get_executor()) {
    if (listener_->options().team_key)
      channel_ = std::make_unique<SecureChannel>(*listener_->options().team_key,
                                                 SecureChannel::Role::kResponder);
  }

  void begin() {
    if (channel_) write_channel_message(channel_->hello());
    do_read();
  }

  void close(const std::string& reason) {
    if (closed_) return;
    closed_ = true;
    ErrorCode ignored;
    socket_.shutdown(tcp::socket::shutdown_both, ignored);
    socket_.close(ignored);
    retry_timer_.cancel();
    listener_->on_closed(*this, reason);
  }

  const std::uint64_t id;
  const std::string remote;
  Clock::time_point last_received;

 private:
  void do_read() {
    socket_.async_read_some(asio::buffer(buffer_),
                            [self = shared_from_this()](const ErrorCode& error, std::size_t bytes) {
                              self->on_read(error, bytes);
                            });
  }

  void on_read(const ErrorCode& error, std::size_t bytes) {
    if (closed_) return;
    if (error)
      return close(error == asio::error::eof ? std::string("connection closed by the peer")
                                             : "read failed: " + error.message());
    last_received = Clock::now();
    listener_->update_counters([&](FrameListenerCounters& counters) { counters.bytes += bytes; });
    decoder_.feed(std::string_view(buffer_.data(), bytes));
    deliver();
  }

  /// Decodes and hands over buffered frames until more bytes are needed (then reads) or the
  /// handler is busy (then retries later, without reading: backpressure).
  void deliver() {
    while (!closed_) {
      if (!pending_) {
        const FrameDecoder::Status status = decoder_.next_payload(payload_);
        if (status == FrameDecoder::Status::kNeedMore) break;
        if (status == FrameDecoder::Status::kError) return reject(decoder_.error());
        if (channel_ && !channel_->established()) {
          if (!on_channel_message()) return;
          continue;
        }
        std::string_view plaintext = payload_;
        std::optional<std::string> opened;
        if (channel_) {
          std::string reason;
          opened = channel_->open(payload_, reason);
          if (!opened) return reject({FrameErrorKind::kUnauthenticated, reason});
          plaintext = *opened;
        }
        FrameError check = parse_envelope(plaintext, decoder_.options().team, envelope_);
        if (check.kind != FrameErrorKind::kNone) return reject(check);
        pending_ = true;
      }
      if (!listener_->on_envelope(*this, envelope_)) {
        // Busy: keep the envelope, stop reading, offer it again shortly.
        listener_->update_counters([](FrameListenerCounters& c) { ++c.busy_pauses; });
        retry_timer_.expires_after(listener_->options().busy_retry);
        retry_timer_.async_wait([self = shared_from_this()](const ErrorCode& wait_error) {
          if (!wait_error && !self->closed_) self->deliver();
        });
        return;
      }
      pending_ = false;
    }
    if (!closed_) do_read();
  }

  bool on_channel_message() {
    std::string reason;
    if (channel_->stage() == SecureChannel::Stage::kAwaitingHello) {
      std::optional<std::string> proof = channel_->accept_hello(payload_, reason);
      if (!proof) {
        reject({FrameErrorKind::kUnauthenticated, "channel handshake failed: " + reason});
        return false;
      }
      write_channel_message(*proof);
      return true;
    }
    if (!channel_->accept_proof(payload_, reason)) {
      reject({FrameErrorKind::kUnauthenticated, "channel handshake failed: " + reason});
      return false;
    }
    return true;
  }

  void reject(const FrameError& error) {
    listener_->on_frame_error(error);
    std::uint64_t suppressed = 0;
    if (listener_->log_limiter.allow("ingest " + std::string(to_string(error.kind)), suppressed))
      spdlog::warn("net: ingest connection #{} from {}: {} frame: {}{}", id, remote,
                   to_string(error.kind), error.reason, suppressed_note(suppressed));
    close(error.reason);
  }

  /// Handshake messages only (ingest never sends anything else).
  void write_channel_message(const std::string& payload) {
    outgoing_.emplace_back();
    append_raw_frame(payload, outgoing_.back());
    if (outgoing_.size() == 1) write_next();
  }

  void write_next() {
    if (outgoing_.empty() || closed_) return;
    asio::async_write(socket_, asio::buffer(outgoing_.front()),
                      [self = shared_from_this()](const ErrorCode& error, std::size_t) {
                        if (self->closed_) return;
                        if (error) return self->close("write failed: " + error.message());
                        self->outgoing_.pop_front();
                        self->write_next();
                      });
  }

  std::shared_ptr<Impl> listener_;
  tcp::socket socket_;
  FrameDecoder decoder_;
  std::vector<char> buffer_;
  asio::steady_timer retry_timer_;
  std::unique_ptr<SecureChannel> channel_;  // with a team key
  std::deque<std::string> outgoing_;        // handshake frames being written
  std::string payload_;
  v1::Envelope envelope_;
  bool pending_ = false;  // envelope_ decoded but not yet taken by the handler
  bool closed_ = false;
};

void FrameListener::Impl::start() {
  if (start_called_.exchange(true)) throw std::logic_error("FrameListener::start called twice");
  const std::vector<std::string> problems = options_.validate();
  if (!problems.empty()) {
    std::string message = "invalid ingest options:";
    for (const std::string& problem : problems) message += "\n  " + problem;
    throw std::invalid_argument(message);
  }
  const tcp::endpoint endpoint(asio::ip::make_address(options_.listen_address), options_.port);
  ErrorCode error;
  acceptor_.open(endpoint.protocol(), error);
  if (!error) acceptor_.set_option(tcp::acceptor::reuse_address(true), error);
  if (!error) acceptor_.bind(endpoint, error);
  if (!error) acceptor_.listen(asio::socket_base::max_listen_connections, error);
  if (error)
    throw std::runtime_error("net: cannot listen for ingest on " + options_.listen_address + ":" +
                             std::to_string(options_.port) + ": " + error.message());
  port_ = acceptor_.local_endpoint().port();
  spdlog::info("net: ingest listening on {}:{} (max frame {} bytes, team '{}', idle timeout {} ms)",
               options_.listen_address, port_.load(), options_.max_frame_bytes, options_.team,
               options_.idle_timeout.count());
  asio::post(strand_, [self = shared_from_this()] {
    if (self->stopping_) return;
    self->do_accept();
    if (self->options_.idle_timeout.count() > 0) self->arm_idle_check();
  });
}

void FrameListener::Impl::do_accept() {
  acceptor_.async_accept([self = shared_from_this()](const ErrorCode& error, tcp::socket socket) {
    if (self->stopping_ || error == asio::error::operation_aborted) return;
    if (error) {
      spdlog::warn("net: ingest accept failed: {}", error.message());
    } else {
      ErrorCode endpoint_error;
      const tcp::endpoint remote = socket.remote_endpoint(endpoint_error);
      const std::string address =
          endpoint_error ? std::string("?")
                         : HostPort{remote.address().to_string(), remote.port()}.to_string();
      if (self->connections_.size() >= self->options_.max_connections) {
        self->update_counters([](FrameListenerCounters& c) { ++c.connections_refused; });
        std::uint64_t suppressed = 0;
        if (self->log_limiter.allow("ingest refused", suppressed))
          spdlog::warn("net: ingest connection from {} refused: {} connections open{}", address,
                       self->connections_.size(), suppressed_note(suppressed));
      } else {
        const std::uint64_t id = self->next_id_++;
        auto connection = std::make_shared<Connection>(self, id, std::move(socket), address);
        self->connections_[id] = connection;
        self->update_counters([&](FrameListenerCounters& c) {
          ++c.connections_accepted;
          c.open_connections = self->connections_.size();
        });
        std::uint64_t suppressed = 0;
        if (self->log_limiter.allow("ingest connection", suppressed))
          spdlog::info("net: ingest connection #{} from {}{}", id, address,
                       suppressed_note(suppressed));
        connection->begin();
      }
    }
    self->do_accept();
  });
}

void FrameListener::Impl::arm_idle_check() {
  // Checked a few times per timeout, so a connection is closed at most 25% late.
  idle_timer_.expires_after(std::max(options_.idle_timeout / 4, std::chrono::milliseconds(1)));
  idle_timer_.async_wait([self = shared_from_this()](const ErrorCode& error) {
    if (error || self->stopping_) return;
    const auto now = Clock::now();
    std::vector<std::shared_ptr<Connection>> idle;
    for (const auto& [id, weak] : self->connections_)
      if (auto connection = weak.lock();
          connection && now - connection->last_received > self->options_.idle_timeout)
        idle.push_back(std::move(connection));
    for (const auto& connection : idle) {
      self->update_counters([](FrameListenerCounters& c) { ++c.idle_timeouts; });
      connection->close("idle for " + std::to_string(self->options_.idle_timeout.count()) + " ms");
    }
    self->arm_idle_check();
  });
}

bool FrameListener::Impl::on_envelope(const Connection& connection, const v1::Envelope& envelope) {
  bool taken = true;
  update_counters([](FrameListenerCounters& c) { ++c.frames; });  // before the handler runs
  if (envelope_handler) {
    try {
      taken = envelope_handler(connection.id, envelope);
    } catch (const std::exception& error) {
      spdlog::error("net: ingest envelope handler threw: {}", error.what());
    } catch (...) {
      spdlog::error("net: ingest envelope handler threw a non-standard exception");
    }
  }
  if (!taken) update_counters([](FrameListenerCounters& c) { --c.frames; });
  return taken;
}

void FrameListener::Impl::on_frame_error(const FrameError& error) {
  update_counters([&](FrameListenerCounters& c) {
    if (error.kind == FrameErrorKind::kOversized)
      ++c.rejected_oversized;
    else if (error.kind == FrameErrorKind::kUnauthenticated)
      ++c.rejected_unauthenticated;
    else
      ++c.rejected_garbage;
  });
}

void FrameListener::Impl::on_closed(const Connection& connection, const std::string& reason) {
  connections_.erase(connection.id);
  update_counters([&](FrameListenerCounters& c) { c.open_connections = connections_.size(); });
  std::uint64_t suppressed = 0;
  if (log_limiter.allow("ingest closed", suppressed))
    spdlog::info("net: ingest connection #{} from {} closed: {}{}", connection.id,
                 connection.remote, reason, suppressed_note(suppressed));
  if (!close_handler) return;
  try {
    close_handler(connection.id, reason);
  } catch (const std::exception& error) {
    spdlog::error("net: ingest close handler threw: {}", error.what());
  } catch (...) {
    spdlog::error("net: ingest close handler threw a non-standard exception");
  }
}

void FrameListener::Impl::stop(bool detach) {
  asio::post(strand_, [self = shared_from_this(), detach] {
    if (detach) {  // from the destructor: no callback runs any more
      self->envelope_handler = nullptr;
      self->close_handler = nullptr;
    }
    if (self->stopping_) return;
    self->stopping_ = true;
    ErrorCode ignored;
    self->acceptor_.close(ignored);
    self->idle_timer_.cancel();
    std::vector<std::shared_ptr<Connection>> open;
    for (const auto& [id, weak] : self->connections_)
      if (auto connection = weak.lock()) open.push_back(std::move(connection));
    for (const auto& connection : open) connection->close("stopping");
  });
}

FrameListener::FrameListener(boost::asio::io_context& io, FrameListenerOptions options)
    : impl_(std::make_shared<Impl>(io, std::move(options))) {}

FrameListener::~FrameListener() { impl_->stop(/*detach=*/true); }

void FrameListener::set_envelope_handler(EnvelopeHandler handler) {
  impl_->envelope_handler = std::move(handler);
}

void FrameListener::set_close_handler(CloseHandler handler) {
  impl_->close_handler = std::move(handler);
}

void FrameListener::start() { impl_->start(); }

void FrameListener::stop() { impl_->stop(); }

std::uint16_t FrameListener::port() const { return impl_->port(); }

FrameListenerCounters FrameListener::counters() const { return impl_->counters(); }

}  // namespace concord::net
