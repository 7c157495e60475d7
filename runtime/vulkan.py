"""Running the SPIR-V target's compute shaders with Vulkan, through the ``vulkan`` Python
package (cffi over the system's loader): lavapipe (Debian's ``mesa-vulkan-drivers``) on a
CPU, or any GPU's driver.

One :class:`Device` per process (the first compute-capable physical device, or the one
``$RDSL_VULKAN_DEVICE`` numbers).  One :class:`Pipeline` per kernel holds its storage buffers
from call to call: a buffer is created when a call needs more room than it has (sizes grow by
powers of two) and reused otherwise, so a loop of calls uploads, dispatches and reads back
without creating anything.  Memory is host-visible and coherent, mapped once.
"""

from __future__ import annotations

import os
import threading
from dataclasses import dataclass
from typing import Any

import numpy as np

PACKAGES = ("the `vulkan` Python package (pip install vulkan) and a Vulkan driver (Debian's "
            "libvulkan1 and mesa-vulkan-drivers for lavapipe)")


class VulkanUnavailable(RuntimeError):
    """No Vulkan: the package, the loader, a device or a feature a kernel needs is missing."""


def _vk() -> Any:
    try:
        import vulkan
    except (ImportError, OSError) as e:
        raise VulkanUnavailable(f"target spirv runs on Vulkan, which needs {PACKAGES} "
                                f"({type(e).__name__}: {str(e).splitlines()[0]})") from None
    return vulkan


@dataclass
class Buffer:
    """A storage buffer bound to host-visible coherent memory, mapped as ``view`` (bytes)."""

    handle: Any
    memory: Any
    size: int
    view: np.ndarray


class Device:
    """A Vulkan instance, device, compute queue and command pool."""

    _instance: Device | None = None
    _lock = threading.Lock()

    @classmethod
    def get(cls) -> Device:
        """The process's device, created on first use."""
        with cls._lock:
            if cls._instance is None:
                cls._instance = cls()
            return cls._instance

    def __init__(self) -> None:
        vk = self.vk = _vk()
        app = vk.VkApplicationInfo(pApplicationName="rdsl", apiVersion=vk.VK_MAKE_VERSION(1, 1, 0))
        try:
            self.instance = vk.vkCreateInstance(vk.VkInstanceCreateInfo(pApplicationInfo=app),
                                                None)
            devices = vk.vkEnumeratePhysicalDevices(self.instance)
        except vk.VkError as e:
            raise VulkanUnavailable(f"no Vulkan instance or device ({type(e).__name__}); "
                                    f"target spirv needs {PACKAGES}") from None
        pick = int(os.environ.get("RDSL_VULKAN_DEVICE", "0"))
        if not devices or pick >= len(devices):
            raise VulkanUnavailable(f"no Vulkan device (found {len(devices)}); target spirv "
                                    f"needs {PACKAGES}")
        self.physical = devices[pick]
        props = vk.vkGetPhysicalDeviceProperties(self.physical)
        self.name = vk.ffi.string(props.deviceName).decode() \
            if not isinstance(props.deviceName, str) else props.deviceName
        self.max_groups = int(props.limits.maxComputeWorkGroupCount[0])
        self.max_buffers = int(props.limits.maxPerStageDescriptorStorageBuffers)
        self.max_range = int(props.limits.maxStorageBufferRange)
        families = vk.vkGetPhysicalDeviceQueueFamilyProperties(self.physical)
        self.family = next(i for i, f in enumerate(families)
                           if f.queueFlags & vk.VK_QUEUE_COMPUTE_BIT)
        self.int64 = bool(vk.vkGetPhysicalDeviceFeatures(self.physical).shaderInt64)
        queue = vk.VkDeviceQueueCreateInfo(queueFamilyIndex=self.family, queueCount=1,
                                           pQueuePriorities=[1.0])
        feats = vk.VkPhysicalDeviceFeatures(shaderInt64=vk.VK_TRUE if self.int64 else 0)
        self.device = vk.vkCreateDevice(self.physical, vk.VkDeviceCreateInfo(
            queueCreateInfoCount=1, pQueueCreateInfos=[queue], pEnabledFeatures=feats), None)
        self.queue = vk.vkGetDeviceQueue(self.device, self.family, 0)
        self.pool = vk.vkCreateCommandPool(self.device, vk.VkCommandPoolCreateInfo(
            queueFamilyIndex=self.family,
            flags=vk.VK_COMMAND_POOL_CREATE_RESET_COMMAND_BUFFER_BIT), None)
        mem = vk.vkGetPhysicalDeviceMemoryProperties(self.physical)
        want = vk.VK_MEMORY_PROPERTY_HOST_VISIBLE_BIT | vk.VK_MEMORY_PROPERTY_HOST_COHERENT_BIT
        self.memory_types = [i for i in range(mem.memoryTypeCount)
                             if mem.memoryTypes[i].propertyFlags & want == want]
        self.submit_lock = threading.Lock()

    def buffer(self, size: int) -> Buffer:
        """A storage buffer of at least ``size`` bytes, mapped."""
        vk = self.vk
        size = max(16, int(size))
        handle = vk.vkCreateBuffer(self.device, vk.VkBufferCreateInfo(
            size=size, usage=vk.VK_BUFFER_USAGE_STORAGE_BUFFER_BIT,
            sharingMode=vk.VK_SHARING_MODE_EXCLUSIVE), None)
        req = vk.vkGetBufferMemoryRequirements(self.device, handle)
        index = next((i for i in self.memory_types if req.memoryTypeBits & (1 << i)), None)
        if index is None:
            raise VulkanUnavailable(f"the Vulkan device `{self.name}` has no host-visible "
                                    "coherent memory for storage buffers")
        memory = vk.vkAllocateMemory(self.device, vk.VkMemoryAllocateInfo(
            allocationSize=req.size, memoryTypeIndex=index), None)
        vk.vkBindBufferMemory(self.device, handle, memory, 0)
        mapped = vk.vkMapMemory(self.device, memory, 0, size, 0)
        return Buffer(handle, memory, size, np.frombuffer(mapped, np.uint8))

    def free(self, buf: Buffer) -> None:
        vk = self.vk
        vk.vkUnmapMemory(self.device, buf.memory)
        vk.vkDestroyBuffer(self.device, buf.handle, None)
        vk.vkFreeMemory(self.device, buf.memory, None)

    def shader(self, code: bytes) -> Any:
        """A shader module of SPIR-V ``code``."""
        vk = self.vk
        return vk.vkCreateShaderModule(self.device, vk.VkShaderModuleCreateInfo(
            codeSize=len(code), pCode=code), None)


class Pipeline:
    """One kernel's compute pipeline, descriptor set and persistent buffers."""

    def __init__(self, device: Device, shader: Any, entry: str, nbindings: int) -> None:
        vk = self.vk = device.vk
        self.dev = device
        if nbindings > device.max_buffers:
            raise VulkanUnavailable(f"kernel entry `{entry}` binds {nbindings} storage "
                                    f"buffers; the Vulkan device `{device.name}` allows "
                                    f"{device.max_buffers} per shader stage")
        d = device.device
        kind = vk.VK_DESCRIPTOR_TYPE_STORAGE_BUFFER
        binds = [vk.VkDescriptorSetLayoutBinding(
            binding=k, descriptorType=kind, descriptorCount=1,
            stageFlags=vk.VK_SHADER_STAGE_COMPUTE_BIT) for k in range(nbindings)]
        self.set_layout = vk.vkCreateDescriptorSetLayout(d, vk.VkDescriptorSetLayoutCreateInfo(
            bindingCount=nbindings, pBindings=binds), None)
        self.layout = vk.vkCreatePipelineLayout(d, vk.VkPipelineLayoutCreateInfo(
            setLayoutCount=1, pSetLayouts=[self.set_layout]), None)
        stage = vk.VkPipelineShaderStageCreateInfo(
            stage=vk.VK_SHADER_STAGE_COMPUTE_BIT, module=shader, pName=entry)
        self.pipeline = vk.vkCreateComputePipelines(d, None, 1, [vk.VkComputePipelineCreateInfo(
            stage=stage, layout=self.layout)], None)[0]
        self.pool = vk.vkCreateDescriptorPool(d, vk.VkDescriptorPoolCreateInfo(
            maxSets=1, poolSizeCount=1,
            pPoolSizes=[vk.VkDescriptorPoolSize(type=kind, descriptorCount=nbindings)]), None)
        self.set = vk.vkAllocateDescriptorSets(d, vk.VkDescriptorSetAllocateInfo(
            descriptorPool=self.pool, descriptorSetCount=1, pSetLayouts=[self.set_layout]))[0]
        self.cmd = vk.vkAllocateCommandBuffers(d, vk.VkCommandBufferAllocateInfo(
            commandPool=device.pool, level=vk.VK_COMMAND_BUFFER_LEVEL_PRIMARY,
            commandBufferCount=1))[0]
        self.fence = vk.vkCreateFence(d, vk.VkFenceCreateInfo(), None)
        self.buffers: list[Buffer | None] = [None] * nbindings
        self.recorded: tuple[int, int] | None = None  # the dispatch size cmd holds

    def _ensure(self, k: int, size: int) -> Buffer:
        """Binding ``k``'s buffer, grown (and the descriptor rewritten) below ``size``."""
        vk, buf = self.vk, self.buffers[k]
        if buf is not None and buf.size >= size:
            return buf
        if buf is not None:
            vk.vkQueueWaitIdle(self.dev.queue)
            self.dev.free(buf)
        buf = self.buffers[k] = self.dev.buffer(1 << max(4, (max(size, 1) - 1).bit_length()))
        info = vk.VkDescriptorBufferInfo(buffer=buf.handle, offset=0, range=buf.size)
        vk.vkUpdateDescriptorSets(self.dev.device, 1, [vk.VkWriteDescriptorSet(
            dstSet=self.set, dstBinding=k, descriptorCount=1,
            descriptorType=vk.VK_DESCRIPTOR_TYPE_STORAGE_BUFFER, pBufferInfo=[info])], 0, None)
        self.recorded = None
        return buf

    def upload(self, k: int, data: np.ndarray | bytes, room: int = 0) -> None:
        """Copy ``data`` to the start of binding ``k`` (at least ``room`` bytes)."""
        raw = np.frombuffer(data, np.uint8) if isinstance(data, bytes) else \
            np.ascontiguousarray(data).reshape(-1).view(np.uint8)
        buf = self._ensure(k, max(raw.size, room))
        buf.view[:raw.size] = raw

    def room(self, k: int, size: int) -> np.ndarray:
        """The first ``size`` bytes of binding ``k``'s mapped memory (grown if need be)."""
        return self._ensure(k, size).view[:size]

    def dispatch(self, n: int, local_size: int) -> None:
        """Run ``n`` invocations and wait for them."""
        vk = self.vk
        groups = -(-n // local_size)
        gx = min(groups, self.dev.max_groups)
        size = (gx, -(-groups // gx))
        if self.recorded != size:
            self._record(*size)
        with self.dev.submit_lock:
            vk.vkQueueSubmit(self.dev.queue, 1, [vk.VkSubmitInfo(
                commandBufferCount=1, pCommandBuffers=[self.cmd])], self.fence)
            vk.vkWaitForFences(self.dev.device, 1, [self.fence], vk.VK_TRUE, 2 ** 63 - 1)
            vk.vkResetFences(self.dev.device, 1, [self.fence])

    def _record(self, gx: int, gy: int) -> None:
        vk = self.vk
        vk.vkResetCommandBuffer(self.cmd, 0)
        vk.vkBeginCommandBuffer(self.cmd, vk.VkCommandBufferBeginInfo())
        vk.vkCmdBindPipeline(self.cmd, vk.VK_PIPELINE_BIND_POINT_COMPUTE, self.pipeline)
        vk.vkCmdBindDescriptorSets(self.cmd, vk.VK_PIPELINE_BIND_POINT_COMPUTE, self.layout,
                                   0, 1, [self.set], 0, None)
        vk.vkCmdDispatch(self.cmd, gx, gy, 1)
        barrier = vk.VkMemoryBarrier(srcAccessMask=vk.VK_ACCESS_SHADER_WRITE_BIT,
                                     dstAccessMask=vk.VK_ACCESS_HOST_READ_BIT)
        vk.vkCmdPipelineBarrier(self.cmd, vk.VK_PIPELINE_STAGE_COMPUTE_SHADER_BIT,
                                vk.VK_PIPELINE_STAGE_HOST_BIT, 0, 1, [barrier], 0, None,
                                0, None)
        vk.vkEndCommandBuffer(self.cmd)
        self.recorded = (gx, gy)
