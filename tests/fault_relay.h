#pragma once
// A fault-injecting TCP relay for tests (issue 14): the latency, jitter and loss a radio link
// adds, which the machines' kernels cannot (netem is not available). It listens on 127.0.0.1 (a
// port the kernel picks) and forwards every connection to a target port, each chunk of bytes
// after
//   latency + uniform(-jitter, +jitter) [+ retransmit_delay with probability loss],
// in order (a chunk never overtakes the one before it, as on one TCP stream: loss on a TCP link
// shows to the application as a retransmission delay, not as missing bytes), and cuts a
// connection (both sides closed) with probability cut per chunk: a link that drops. Bounded: a
// direction stops reading while more than max_queued_bytes wait for their delivery time.
// Runs on its own thread; everything else happens on that thread. Counters are atomic.
#include <atomic>
#include <boost/asio/ip/tcp.hpp>
#include <boost/asio/steady_timer.hpp>
#include <boost/asio/write.hpp>
#include <chrono>
#include <cstdint>
#include <deque>
#include <memory>
#include <random>
#include <thread>
#include <vector>

namespace concord::testing {

struct FaultProfile {
  std::chrono::milliseconds latency{0};
  std::chrono::milliseconds jitter{0};
  double loss = 0.0;  ///< probability that a chunk waits retransmit_delay more
  std::chrono::milliseconds retransmit_delay{200};
  double cut = 0.0;  ///< probability per chunk that the connection is cut
  std::size_t max_queued_bytes = 4 << 20;
  unsigned seed = 1;
};

class FaultRelay {
 public:
  FaultRelay(std::uint16_t target_port, FaultProfile profile)
      : target_port_(target_port), profile_(profile), random_(profile.seed) {
    namespace ip = boost::asio::ip;
    acceptor_.open(ip::tcp::v4());
    acceptor_.set_option(ip::tcp::acceptor::reuse_address(true));
    acceptor_.bind({ip::make_address_v4("127.0.0.1"), 0});
    acceptor_.listen();
    port_ = acceptor_.local_endpoint().port();
    accept();
    thread_ = std::thread([this] { io_.run(); });
  }
  FaultRelay(const FaultRelay&) = delete;
  FaultRelay& operator=(const FaultRelay&) = delete;
  ~FaultRelay() {
    io_.stop();
    thread_.join();
  }

  std::uint16_t port() const { return port_; }
  std::uint64_t connections() const { return connections_; }
  std::uint64_t chunks() const { return chunks_; }
  std::uint64_t bytes() const { return bytes_; }
  std::uint64_t losses() const { return losses_; }
  std::uint64_t cuts() const { return cuts_; }

 private:
  using Socket = boost::asio::ip::tcp::socket;
  using Clock = std::chrono::steady_clock;

  struct Chunk {
    Clock::time_point due;
    std::vector<char> bytes;
  };
  struct Link;
  /// One direction of a connection: reads from `from`, delivers to `to`.
  struct Direction {
    Socket* from = nullptr;
    Socket* to = nullptr;
    std::deque<Chunk> queue;
    std::size_t queued_bytes = 0;
    Clock::time_point last_due{};
    bool reading = false;
    bool writing = false;
    bool ended = false;  // `from` closed: deliver what is queued, then close the link
    std::unique_ptr<boost::asio::steady_timer> timer;
    std::vector<char> buffer = std::vector<char>(16384);
  };
  struct Link {
    explicit Link(boost::asio::io_context& io) : client(io), server(io) {}
    Socket client;
    Socket server;
    Direction up;    // client -> server
    Direction down;  // server -> client
    bool closed = false;
  };

  void accept() {
    auto link = std::make_shared<Link>(io_);
    acceptor_.async_accept(link->client, [this, link](const boost::system::error_code& error) {
      if (error) return;
      ++connections_;
      namespace ip = boost::asio::ip;
      link->server.async_connect(
          {ip::make_address_v4("127.0.0.1"), target_port_},
          [this, link](const boost::system::error_code& connect_error) {
            if (connect_error) return close(link);
            start(link, link->up, link->client, link->server);
            start(link, link->down, link->server, link->client);
          });
      accept();
    });
  }

  void start(const std::shared_ptr<Link>& link, Direction& direction, Socket& from, Socket& to) {
    direction.from = &from;
    direction.to = &to;
    direction.timer = std::make_unique<boost::asio::steady_timer>(io_);
    read(link, direction);
  }

  void read(const std::shared_ptr<Link>& link, Direction& direction) {
    if (link->closed || direction.ended || direction.reading || direction.queued_bytes > profile_.max_queued_bytes)
      return;
    direction.reading = true;
    direction.from->async_read_some(
        boost::asio::buffer(direction.buffer),
        [this, link, &direction](const boost::system::error_code& error, std::size_t n) {
          direction.reading = false;
          if (error) {
            direction.ended = true;
            if (direction.queue.empty() && !direction.writing) close(link);
            return;
          }
          ++chunks_;
          bytes_ += n;
          if (profile_.cut > 0.0 && unit_(random_) < profile_.cut) {
            ++cuts_;
            return close(link);
          }
          auto delay = std::chrono::duration_cast<Clock::duration>(profile_.latency);
          if (profile_.jitter.count() > 0) {
            const double jitter = (2.0 * unit_(random_) - 1.0) *
                                  std::chrono::duration<double>(profile_.jitter).count();
            delay += std::chrono::duration_cast<Clock::duration>(
                std::chrono::duration<double>(jitter));
          }
          if (profile_.loss > 0.0 && unit_(random_) < profile_.loss) {
            ++losses_;
            delay += profile_.retransmit_delay;
          }
          const Clock::time_point due = std::max(direction.last_due, Clock::now() + delay);
          direction.last_due = due;
          direction.queue.push_back(
              {due, std::vector<char>(direction.buffer.begin(),
                                      direction.buffer.begin() + static_cast<std::ptrdiff_t>(n))});
          direction.queued_bytes += n;
          deliver(link, direction);
          read(link, direction);
        });
  }

  void deliver(const std::shared_ptr<Link>& link, Direction& direction) {
    if (link->closed || direction.writing || direction.queue.empty()) return;
    direction.writing = true;
    direction.timer->expires_at(direction.queue.front().due);
    direction.timer->async_wait([this, link, &direction](const boost::system::error_code& error) {
      if (error || link->closed) return;
      boost::asio::async_write(
          *direction.to, boost::asio::buffer(direction.queue.front().bytes),
          [this, link, &direction](const boost::system::error_code& write_error, std::size_t n) {
            direction.writing = false;
            if (write_error) return close(link);
            direction.queued_bytes -= n;
            direction.queue.pop_front();
            if (direction.ended && direction.queue.empty()) return close(link);
            deliver(link, direction);
            read(link, direction);  // resumes a direction paused by its bound
          });
    });
  }

  void close(const std::shared_ptr<Link>& link) {
    if (link->closed) return;
    link->closed = true;
    boost::system::error_code ignored;
    link->client.close(ignored);
    link->server.close(ignored);
    if (link->up.timer) link->up.timer->cancel();
    if (link->down.timer) link->down.timer->cancel();
  }

  boost::asio::io_context io_;
  boost::asio::ip::tcp::acceptor acceptor_{io_};
  std::uint16_t target_port_;
  std::uint16_t port_ = 0;
  FaultProfile profile_;
  std::mt19937 random_;
  std::uniform_real_distribution<double> unit_{0.0, 1.0};
  std::atomic<std::uint64_t> connections_{0}, chunks_{0}, bytes_{0}, losses_{0}, cuts_{0};
  std::thread thread_;
};

}  // namespace concord::testing
