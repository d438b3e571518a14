#include "distributed/store_process_group.h"

#include <cstring>
#include <exception>

#include "flat/core/error.h"

namespace flat::distributed::detail {
namespace {

// Collective number k uses keys "flat/c<k>/<rank>". Every rank sums the
// contributions in rank order, so all ranks get bitwise the same result. The
// last rank to finish reading deletes the keys, so the store stays small.
class StoreProcessGroup : public ProcessGroup {
 public:
  StoreProcessGroup(c10::intrusive_ptr<c10d::Store> store, int64_t rank, int64_t world_size,
                    std::chrono::milliseconds timeout)
      : ProcessGroup(rank, world_size), store_(std::move(store)), timeout_(timeout) {}

  // Rank 0 serves the store: it waits (bounded) until every rank has said
  // goodbye, so that no rank loses the store in the middle of its last
  // collective. Not after a failure, nor while an exception unwinds: then a
  // peer may be dead, and the error must reach the caller now.
  ~StoreProcessGroup() override {
    if (failed_ || std::uncaught_exceptions() > 0) return;
    try {
      if (store_->add("flat/exit", 1) == world_size()) store_->set("flat/all_exited", std::vector<uint8_t>{1});
      if (rank() == 0) store_->wait({"flat/all_exited"}, timeout_);
    } catch (const std::exception&) {
      // A peer is gone already; nothing left to protect.
    }
  }

  std::string backend() const override { return "store"; }

  void allreduce_sum(at::Tensor& tensor) override {
    const std::string tag = next_tag();
    try {
      const at::Tensor mine = tensor.detach().to(at::kCPU).contiguous();
      store_->set(tag + std::to_string(rank()), bytes_of(mine));
      at::Tensor sum;
      for (int64_t q = 0; q < world_size(); ++q) {
        const at::Tensor part = q == rank() ? mine : fetch(tag, q, mine, "allreduce");
        sum = q == 0 ? part.clone() : sum.add_(part);
      }
      finish(tag);
      tensor.copy_(sum);
    } catch (const c10::Error& e) {
      lost_store("allreduce", e);
    }
  }

  void broadcast(at::Tensor& tensor, int64_t root) override {
    FLAT_CHECK(root >= 0 && root < world_size(), "distributed: broadcast from rank " + std::to_string(root) +
                                                     " outside a world of " + std::to_string(world_size()));
    const std::string tag = next_tag();
    try {
      const at::Tensor mine = tensor.detach().to(at::kCPU).contiguous();
      if (rank() == root) {
        store_->set(tag + std::to_string(root), bytes_of(mine));
      } else {
        tensor.copy_(fetch(tag, root, mine, "broadcast"));
      }
      finish(tag);
    } catch (const c10::Error& e) {
      lost_store("broadcast", e);
    }
  }

 private:
  std::string next_tag() { return "flat/c" + std::to_string(collective_++) + "/"; }

  static std::vector<uint8_t> bytes_of(const at::Tensor& t) {
    const auto* p = static_cast<const uint8_t*>(t.data_ptr());
    return std::vector<uint8_t>(p, p + t.nbytes());
  }

  std::string where(const std::string& what, int64_t peer) const {
    return "distributed: rank " + std::to_string(rank()) + ": " + what + " #" + std::to_string(collective_ - 1) +
           " waiting for rank " + std::to_string(peer);
  }

  // Rank `peer`'s contribution, shaped like `like`; throws naming both ranks
  // when it does not come within the timeout or the store is gone.
  at::Tensor fetch(const std::string& tag, int64_t peer, const at::Tensor& like, const std::string& what) {
    std::vector<uint8_t> data;
    const auto start = std::chrono::steady_clock::now();
    try {
      store_->wait({tag + std::to_string(peer)}, timeout_);
      data = store_->get(tag + std::to_string(peer));
    } catch (const c10::Error& e) {
      failed_ = true;
      const auto waited = std::chrono::duration_cast<std::chrono::milliseconds>(std::chrono::steady_clock::now() - start);
      fail(where(what, peer) + ": no data after " + std::to_string(waited.count()) + " ms (timeout " +
           std::to_string(timeout_.count()) + " ms) or the store is gone (rank " + std::to_string(peer) +
           " dead, stuck or unreachable): " + e.what_without_backtrace());
    }
    FLAT_CHECK(data.size() == like.nbytes(), where(what, peer) + ": it sent " + std::to_string(data.size()) +
                                                 " bytes, this rank " + std::to_string(like.nbytes()) +
                                                 " (the ranks disagree on the tensors)");
    at::Tensor out = at::empty_like(like);
    if (!data.empty()) std::memcpy(out.data_ptr(), data.data(), data.size());
    return out;
  }

  // The last of the ranks to be done deletes the collective's keys.
  void finish(const std::string& tag) {
    if (store_->add(tag + "done", 1) < world_size()) return;
    for (int64_t q = 0; q < world_size(); ++q) store_->deleteKey(tag + std::to_string(q));
    store_->deleteKey(tag + "done");
  }

  // A store operation other than the wait failed: rank 0 serves the store.
  [[noreturn]] void lost_store(const std::string& what, const c10::Error& e) {
    failed_ = true;
    fail("distributed: rank " + std::to_string(rank()) + ": " + what + " #" + std::to_string(collective_ - 1) +
         ": lost the store served by rank 0 (rank 0 dead or unreachable): " + e.what_without_backtrace());
  }

  c10::intrusive_ptr<c10d::Store> store_;
  std::chrono::milliseconds timeout_;
  int64_t collective_ = 0;
  bool failed_ = false;
};

}  // namespace

std::unique_ptr<ProcessGroup> make_store_process_group(c10::intrusive_ptr<c10d::Store> store, int64_t rank,
                                                       int64_t world_size, std::chrono::milliseconds timeout) {
  return std::make_unique<StoreProcessGroup>(std::move(store), rank, world_size, timeout);
}

}  // namespace flat::distributed::detail
